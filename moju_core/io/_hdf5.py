"""The HDF5 reader: root datasets only, no links or data in other files."""

from __future__ import annotations

import os
from typing import IO

import h5py

from moju_core.errors import MeasurementError
from moju_core.io._declared import DATASET_NAMES, Declared, measurements_from_declared
from moju_core.io._sources import Admit, ShortTracks, Source
from moju_core.io.measurements import Measurements


class _LeavesFile(Exception):
    """An HDF5 path crosses a link to another file (internal to the HDF5 reader)."""


#: Soft links followed one after the other before a path counts as a loop.
_MAX_SOFT_LINK_HOPS = 32


def _h5_resolve(h5: h5py.File, path: str, hops: int = 0) -> str | None:
    """``path`` with every soft link on it followed: a path of hard links only, or None
    when nothing is there.

    Raises ``_LeavesFile`` when the path crosses a link to another file (external or
    user-defined) at any depth, through soft links too, or loops.
    """
    if hops > _MAX_SOFT_LINK_HOPS:
        raise _LeavesFile("soft links that loop")
    current = ""
    for part in (part for part in path.split("/") if part and part != "."):
        group = h5[current or "/"]
        if not isinstance(group, h5py.Group):
            return None
        link = group.get(part, getlink=True)
        if link is None:
            return None
        if isinstance(link, h5py.SoftLink):
            target = link.path if link.path.startswith("/") else f"{current}/{link.path}"
            resolved = _h5_resolve(h5, target, hops + 1)
            if resolved is None:
                return None
            current = resolved
        elif isinstance(link, h5py.HardLink):
            current = f"{current}/{part}"
        else:
            raise _LeavesFile(f"a link to another file ({type(link).__name__})")
    return current or "/"


def _h5_declared(h5: h5py.File, source_name: str) -> dict[str, Declared]:
    declared = {}
    for name in DATASET_NAMES:
        try:
            path = _h5_resolve(h5, name)
        except _LeavesFile as exc:
            raise MeasurementError(
                f"{name} in {source_name} is a link to another file, or leads to one through "
                f"{exc}; store the data in the file itself"
            ) from None
        if path is None:
            if h5.get(name, getlink=True) is not None:  # a soft link to nothing
                raise MeasurementError(
                    f"{name} in {source_name} is a link to nothing; {name} must be a plain "
                    "array at the root of the file"
                )
            continue
        dataset = h5.get(path)
        if isinstance(dataset, h5py.Group):
            raise MeasurementError(
                f"{name} in {source_name} is an HDF5 group; {name} must be a dataset (a plain "
                "array) at the root of the file"
            )
        if not isinstance(dataset, h5py.Dataset):
            raise MeasurementError(
                f"{name} in {source_name} is not a dataset; {name} must be a plain array at the "
                "root of the file"
            )
        # Virtual and external datasets read other files of the machine that opens them.
        if dataset.is_virtual or dataset.external:
            raise MeasurementError(
                f"{name} in {source_name} refers to data in other files; store the data in the "
                "file itself"
            )
        if dataset.shape is None:
            raise MeasurementError(f"{name} in {source_name} is an empty (null) dataset")
        declared[name] = Declared(
            tuple(dataset.shape), dataset.dtype, lambda dataset=dataset: dataset[()]
        )
    return declared


def read_h5(
    source: Source,
    handle: IO[bytes],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
    short_tracks: ShortTracks = "refuse",
) -> Measurements:
    # A path lets HDF5 use its own file driver, which is faster than going through Python.
    target = source if isinstance(source, (str, os.PathLike)) else handle
    try:
        with h5py.File(target, "r") as h5:
            declared = _h5_declared(h5, source_name)
            return measurements_from_declared(
                declared, source_name, max_frames, max_points, admit, short_tracks
            )
    except MeasurementError:
        raise
    except Exception as exc:
        raise MeasurementError(
            f"could not read {source_name} as HDF5: {exc}. Check that the file is complete"
        ) from exc
