"""From the shapes and dtypes a file declares to :class:`Measurements`: the size checks
that run before any data is read, shared by the npz and HDF5 readers.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from moju_core.errors import MeasurementError
from moju_core.io._sources import Admit, ShortTracks, refuse_oversized
from moju_core.io.measurements import Measurements
from moju_core.validation import check_dtype, tracks_to_W

_OPTIONAL_NAMES = ("visibility", "R", "gt", "faces", "colors", "K", "frame_size")
#: Exact shapes of the camera datasets (checked before their data is read).
_CAMERA_SHAPES = {"K": (3, 3), "frame_size": (2,)}
DATASET_NAMES = ("W", "tracks", *_OPTIONAL_NAMES)
_EXPECTED_MAIN = "W (2F x P: rows 2f, 2f+1 are x, y of frame f) or tracks (F x P x 2)"


# A triangulated surface of P vertices has about 2P triangles; 4P leaves room for any honest
# mesh while bounding what a hostile file can make us read.
_MAX_FACES_PER_POINT = 4


@dataclass(frozen=True)
class Declared:
    """Shape and dtype a file declares for one dataset, and how to read its data."""

    shape: tuple[int, ...]
    dtype: np.dtype
    read: Callable[[], np.ndarray]


def _main_size(name: str, declared: Declared) -> tuple[int, int]:
    """(F, P) declared by the W or tracks header; the exact checks come after reading."""
    shape = declared.shape
    if name == "W":
        if len(shape) != 2:
            raise MeasurementError(
                f"W has shape {shape} ({len(shape)}-D); it needs shape (2F, P) with rows 2f, "
                "2f+1 the x, y of frame f"
            )
        return (shape[0] + 1) // 2, shape[1]
    if len(shape) != 3 or shape[2] != 2:
        raise MeasurementError(
            f"tracks has shape {shape}; it needs shape (F, P, 2): the (x, y) position of every "
            "point in every frame"
        )
    return shape[0], shape[1]


def _largest_allowed(name: str, n_frames: int, n_points: int, max_points: int | None) -> int:
    """Most elements a well-formed optional dataset can hold for F frames and P points."""
    if name == "R":
        return 6 * n_frames
    if name == "visibility":
        return n_frames * n_points
    if name == "gt":
        return 3 * n_frames * n_points
    if name == "colors":
        return 4 * n_points
    if name in _CAMERA_SHAPES:
        return int(np.prod(_CAMERA_SHAPES[name]))
    if max_points is None:  # faces: only bounded when the caller sets limits
        return -1
    return 3 * _MAX_FACES_PER_POINT * max_points


def measurements_from_declared(
    declared: Mapping[str, Declared],
    source_name: str,
    max_frames: int | None,
    max_points: int | None,
    admit: Admit | None = None,
    short_tracks: ShortTracks = "refuse",
) -> Measurements:
    """Check headers, read the datasets and validate them into :class:`Measurements`.

    ``short_tracks="drop"`` leaves out the points seen in fewer than 2 frames
    (:meth:`Measurements.of_solvable_points`) instead of refusing the file.
    """
    if "W" in declared and "tracks" in declared:
        raise MeasurementError(
            f"{source_name} holds both W and tracks; keep one of them, the two would disagree"
        )
    main = "W" if "W" in declared else "tracks" if "tracks" in declared else None
    if main is None:
        raise MeasurementError(
            f"{source_name} has no dataset named W or tracks; store the measurements as "
            f"{_EXPECTED_MAIN}"
        )
    check_dtype(main, declared[main].dtype)
    n_frames, n_points = _main_size(main, declared[main])
    origin = f"{main} declares shape {declared[main].shape}"
    refuse_oversized(source_name, origin, n_frames, n_points, max_frames, max_points)
    if admit is not None:
        admit(n_frames, n_points)
    for name in _OPTIONAL_NAMES:
        if name not in declared:
            continue
        if not (name == "visibility" and declared[name].dtype.kind == "b"):
            integer = name in ("visibility", "faces", "colors", "frame_size")
            check_dtype(name, declared[name].dtype, integer=integer)
        if name in _CAMERA_SHAPES and declared[name].shape != _CAMERA_SHAPES[name]:
            raise MeasurementError(
                f"{name} in {source_name} has shape {declared[name].shape}; it needs shape "
                f"{_CAMERA_SHAPES[name]}: "
                + (
                    "the 3 x 3 camera matrix in pixels"
                    if name == "K"
                    else "(width, height) of the frames in pixels"
                )
            )
        size = int(np.prod(declared[name].shape, dtype=object))
        largest = _largest_allowed(name, n_frames, n_points, max_points)
        if largest >= 0 and size > largest:
            raise MeasurementError(
                f"{name} in {source_name} declares shape {declared[name].shape}, more values "
                f"than {n_frames} frames and {n_points} points allow; check that it belongs to "
                f"this {main}"
            )
    arrays = {name: declared[name].read() for name in DATASET_NAMES if name in declared}
    W = arrays["W"] if main == "W" else tracks_to_W(arrays["tracks"])
    build = Measurements.of_solvable_points if short_tracks == "drop" else Measurements
    return build(
        W=W,
        rotations=arrays.get("R"),
        ground_truth=arrays.get("gt"),
        faces=arrays.get("faces"),
        colors=arrays.get("colors"),
        visibility=arrays.get("visibility"),
        intrinsics=arrays.get("K"),
        frame_size=arrays.get("frame_size"),
    )
