"""Reading and writing measurement files (npz, HDF5 or CSV)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from moju_core.errors import MeasurementError
from moju_core.io._csv import CSV_COLUMNS, read_csv
from moju_core.io._hdf5 import read_h5
from moju_core.io._npz import read_npz
from moju_core.io._sources import (
    FORMAT_ALIASES,
    FORMATS,
    Admit,
    PathLike,
    ShortTracks,
    Source,
    binary_input,
    check_limit,
    check_short_tracks,
    detect_format,
    display_name,
)
from moju_core.io.atomic import atomic_output
from moju_core.io.measurements import Measurements


def read_measurements(
    source: Source,
    *,
    format: str | None = None,
    max_points: int | None = None,
    max_frames: int | None = None,
    admit: Admit | None = None,
    short_tracks: ShortTracks = "refuse",
) -> Measurements:
    """Read and validate measurements from an npz, HDF5 or CSV file.

    Parameters
    ----------
    source : str, os.PathLike or binary file object
        A path, or an open binary file (an upload) read from its start.
    format : {"npz", "h5", "csv"} or None, default None
        File format (``"hdf5"`` is accepted for ``"h5"``). When None it is detected from the
        first bytes (zip: npz, HDF5 signature: h5), else from the file extension, else CSV.
    max_points, max_frames : int or None, default None
        Largest P and F accepted. They are checked against the sizes a file declares before
        its data is read, so an oversized upload costs no memory.
    admit : callable (F, P) -> None, optional
        Called once the number of frames F and points P is known and before any array of
        that size is built: from the headers for npz and HDF5, after a first streamed pass
        over the rows (one chunk in memory) for CSV. It refuses a file by raising
        :class:`MeasurementTooLarge` (e.g. when the solver's memory estimate is too large).
    short_tracks : {"refuse", "drop"}, default "refuse"
        Points observed in fewer than 2 frames: refuse the file, or leave them out with a
        warning that says how many (as tracks of a video are,
        :func:`moju_core.validation.solvable_points`); their ground truth and colours go too,
        and triangles that use them.

    Returns
    -------
    Measurements
        W (2F, P) float64 (NaN where a point is not observed), its visibility (None when
        nothing is missing) and the optional datasets found in the file, all validated.

    Raises
    ------
    MeasurementError
        For anything unusable: unreadable or truncated files, missing W/tracks, pickled or
        non-numeric data, groups or links where datasets belong, wrong shapes, sizes above the
        limits, infinite values, NaN in one coordinate only, a visibility that disagrees with
        W, points observed in fewer than 2 frames, frames observing fewer than 3 points,
        repeated CSV rows.
    """
    check_limit(max_points, "max_points")
    check_limit(max_frames, "max_frames")
    check_short_tracks(short_tracks)
    if format is not None:
        if format.lower() not in FORMAT_ALIASES:
            raise MeasurementError(
                f"unknown input format {format!r}; use one of {', '.join(FORMATS)}"
            )
        format = FORMAT_ALIASES[format.lower()]
    source_name = display_name(source)
    with binary_input(source, source_name) as handle:
        if format is None:
            format = detect_format(handle, source, source_name)
        if format == "npz":
            return read_npz(handle, source_name, max_frames, max_points, admit, short_tracks)
        if format == "h5":
            return read_h5(source, handle, source_name, max_frames, max_points, admit, short_tracks)
        return read_csv(handle, source_name, max_frames, max_points, admit, short_tracks)


def _measurement_arrays(measurements: Measurements) -> dict[str, np.ndarray]:
    arrays = {"W": measurements.W}
    optional = {
        "visibility": measurements.visibility,
        "R": measurements.rotations,
        "gt": measurements.ground_truth,
        "faces": measurements.faces,
        "colors": measurements.colors,
        "frame_size": (
            None
            if measurements.frame_size is None
            else np.asarray(measurements.frame_size, dtype=np.int64)
        ),
        # The default camera is not stored: read back, it is derived from the frame size again
        # and still says "default".
        "K": (
            None
            if measurements.intrinsics is None or measurements.intrinsics.origin == "default"
            else measurements.intrinsics.K
        ),
    }
    arrays.update({name: value for name, value in optional.items() if value is not None})
    return arrays


def write_measurements(path: PathLike, measurements: Measurements) -> Path:
    """Write measurements in the input file contract (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        Target file; the format follows the extension: ``.npz`` (compressed), ``.h5`` /
        ``.hdf5``, or ``.csv`` (long format ``frame,point,x,y``; W only, one row per observed
        pair).
    measurements : Measurements
        What to write; datasets that are None are left out.

    Returns
    -------
    Path
        The path written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".h5", ".hdf5", ".csv"):
        raise ValueError(
            f"cannot tell the format of {path.name}: use the extension .npz, .h5, .hdf5 or .csv"
        )
    arrays = _measurement_arrays(measurements)
    # CSV keeps the visibility as its missing rows.
    extra = sorted(set(arrays) - {"W", "visibility"})
    if suffix == ".csv" and extra:
        raise ValueError(
            f"CSV holds only the tracks, not {', '.join(extra)}; write .npz or .h5 to keep them"
        )
    with atomic_output(path) as temporary:
        if suffix == ".npz":
            # Inputs are written once and shipped as examples, so smaller beats faster here.
            with open(temporary, "wb") as handle:
                np.savez_compressed(handle, **arrays)
        elif suffix == ".csv":
            n_frames, n_points = measurements.n_frames, measurements.n_points
            tracks = measurements.W.reshape(n_frames, 2, n_points)
            frame_index, point_index = np.divmod(np.arange(n_frames * n_points), n_points)
            table = np.column_stack(
                [frame_index, point_index, tracks[:, 0].ravel(), tracks[:, 1].ravel()]
            )
            if measurements.visibility is not None:  # unobserved pairs get no row
                table = table[measurements.visibility.ravel()]
            np.savetxt(
                temporary,
                table,
                fmt=["%d", "%d", "%.17g", "%.17g"],
                delimiter=",",
                header=",".join(CSV_COLUMNS),
                comments="",
            )
        else:
            with h5py.File(temporary, "w") as h5:
                for name, value in arrays.items():
                    h5.create_dataset(name, data=value)
    return path
