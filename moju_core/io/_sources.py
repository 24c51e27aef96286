"""Where an input comes from: its name in messages, a seekable handle on it, its format,
and the size limits a caller sets.
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Literal

from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.file_types import HEAD_BYTES, array_file_type

PathLike = str | os.PathLike
Source = str | os.PathLike | IO[bytes]
#: Called with (F, P) once a file's sizes are known and before its data is read; raises
#: MeasurementTooLarge (or another MeasurementError) to refuse the file.
Admit = Callable[[int, int], None]

#: What a reader does with points observed in fewer than 2 frames: refuse the file (the
#: default) or leave them out with a warning (:func:`moju_core.validation.solvable_points`).
ShortTracks = Literal["refuse", "drop"]
SHORT_TRACKS = ("refuse", "drop")

#: Input formats understood by :func:`read_measurements`.
FORMATS = ("npz", "h5", "csv")
FORMAT_ALIASES = {"npz": "npz", "h5": "h5", "hdf5": "h5", "csv": "csv"}
_EXTENSION_FORMATS = {".npz": "npz", ".h5": "h5", ".hdf5": "h5", ".hdf": "h5", ".csv": "csv"}


def display_name(source: Source) -> str:
    """The name of ``source`` in messages: its base name, or "the uploaded file"."""
    # Only the base name: an error message must not reveal the server's directory layout.
    if isinstance(source, (str, os.PathLike)):
        return Path(source).name
    name = getattr(source, "name", None)
    return Path(name).name if isinstance(name, str) and name else "the uploaded file"


@contextlib.contextmanager
def binary_input(source: Source, source_name: str) -> Iterator[IO[bytes]]:
    """Yield a seekable binary file positioned at the start of ``source``."""
    if isinstance(source, (str, os.PathLike)):
        try:
            handle = open(source, "rb")
        except OSError as exc:
            raise MeasurementError(f"could not open {source_name}: {exc.strerror}") from exc
        with handle:
            yield handle
        return
    if not (hasattr(source, "seekable") and source.seekable()):
        # zipfile and h5py need to seek; a pipe or socket is buffered in memory.
        yield io.BytesIO(source.read())
        return
    source.seek(0)
    yield source


def detect_format(handle: IO[bytes], source: Source, source_name: str) -> str:
    kind = array_file_type(handle.read(HEAD_BYTES))
    handle.seek(0)
    if kind in ("npz", "h5"):
        return kind
    if kind == "npy":
        raise MeasurementError(
            f"{source_name} is a .npy file (one bare array); save the tracks in an npz with a "
            "name, e.g. np.savez(path, W=W)"
        )
    name = source if isinstance(source, (str, os.PathLike)) else getattr(source, "name", None)
    suffix = Path(name).suffix.lower() if isinstance(name, (str, os.PathLike)) else ""
    return _EXTENSION_FORMATS.get(suffix, "csv")


def check_limit(limit: int | None, what: str) -> None:
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
        raise ValueError(f"{what} limit must be a positive integer or None, got {limit!r}")


def check_short_tracks(short_tracks: str) -> None:
    if short_tracks not in SHORT_TRACKS:
        raise ValueError(f"short_tracks must be one of {SHORT_TRACKS}, got {short_tracks!r}")


def refuse_oversized(
    source_name: str,
    origin: str,
    n_frames: int,
    n_points: int,
    max_frames: int | None,
    max_points: int | None,
) -> None:
    too_many_frames = max_frames is not None and n_frames > max_frames
    too_many_points = max_points is not None and n_points > max_points
    if too_many_frames or too_many_points:
        limits = []
        if max_frames is not None:
            limits.append(f"{max_frames} frames")
        if max_points is not None:
            limits.append(f"{max_points} points")
        raise MeasurementTooLarge(
            f"{source_name} holds {n_frames} frames x {n_points} points ({origin}); the limit "
            f"is {' and '.join(limits)}. Send fewer frames or subsample the points"
        )
