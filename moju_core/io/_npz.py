"""The npz reader: member headers read first, data only once the sizes are accepted."""

from __future__ import annotations

import functools
import zipfile
from typing import IO

import numpy as np
import numpy.lib.format as npy_format

from moju_core.errors import MeasurementError
from moju_core.io._declared import DATASET_NAMES, Declared, measurements_from_declared
from moju_core.io._sources import Admit, ShortTracks
from moju_core.io.measurements import Measurements


def _npz_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> tuple[tuple, np.dtype, int]:
    """Shape, dtype and data offset from a member's .npy header, without reading the data."""
    with archive.open(info) as member:
        version = npy_format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = npy_format.read_array_header_1_0(member)
        elif version in ((2, 0), (3, 0)):
            # 3.0 only allows UTF-8 in structured field names, which are refused anyway.
            shape, _, dtype = npy_format.read_array_header_2_0(member)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
        return tuple(shape), dtype, member.tell()


def _read_npz_member(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, declared_bytes: int, source_name: str
) -> np.ndarray:
    """Read one .npy member whose header promised ``declared_bytes`` (header included)."""
    # A header may promise far more than the member holds; numpy would allocate the promised
    # size before noticing.
    if info.file_size < declared_bytes:
        raise MeasurementError(
            f"{info.filename} in {source_name} is truncated: its header declares "
            f"{declared_bytes} bytes but the member holds {info.file_size}"
        )
    with archive.open(info) as stream:
        return npy_format.read_array(stream, allow_pickle=False)


def read_npz(
    handle: IO[bytes],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
    short_tracks: ShortTracks = "refuse",
) -> Measurements:
    try:
        with zipfile.ZipFile(handle) as archive:
            members = {
                info.filename[: -len(".npy")]: info
                for info in archive.infolist()
                if info.filename.endswith(".npy")
            }
            declared = {}
            for name in DATASET_NAMES:
                if name not in members:
                    continue
                info = members[name]
                shape, dtype, offset = _npz_header(archive, info)
                size = offset + dtype.itemsize * int(np.prod(shape, dtype=object))
                read = functools.partial(_read_npz_member, archive, info, size, source_name)
                declared[name] = Declared(shape, dtype, read)
            return measurements_from_declared(
                declared, source_name, max_frames, max_points, admit, short_tracks
            )
    except MeasurementError:
        raise
    except Exception as exc:
        # zipfile, zlib and numpy raise a zoo of types on corrupt input; report them as one.
        raise MeasurementError(
            f"could not read {source_name} as npz: {exc}. Check that the file is complete and "
            "was written with numpy.savez"
        ) from exc
