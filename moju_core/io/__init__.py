"""Reading measurements and writing results: the file contract shared by the CLI, API and worker.

Input files (npz, HDF5 or CSV) may come from strangers, so readers never unpickle, look at the
declared shape and dtype of every dataset before reading its data, refuse sizes above the
caller's limits, and turn every failure of the underlying libraries into a
:class:`~moju_core.errors.MeasurementError` that says what is wrong.

Dataset names of an input file (npz members or HDF5 root datasets):

* ``W`` (2F x P): rows 2f, 2f+1 are x, y of frame f; or ``tracks`` (F x P x 2). A point that
  is not observed in a frame is NaN there (x and y both);
* optional ``visibility`` (F x P bool, True = observed), which must agree with the NaN of W;
* optional ``R`` (F x 2 x 3) known rotations, ``gt`` (F x P x 3) ground truth,
  ``faces`` (M x 3) triangle indices, ``colors`` (P x 3, or P x 4 with alpha) in 0..255;
* optional camera: ``K`` (3 x 3, pixels) the camera matrix of W's pixels and ``frame_size``
  (2,) integers = (width, height) in pixels (:mod:`moju_core.cameras.intrinsics`). With a
  ``frame_size`` and no ``K`` the default camera of that size is used (focal length 1.2 x the
  larger side, principal point at the image centre; its origin says ``"default"``); with
  neither, the tracks have no camera (orthographic). Both are checked from their headers
  (exact shapes (3, 3) and (2,)) before their data is read.

Other datasets are ignored. A CSV input is in long format with the header ``frame,point,x,y``,
one row per observed (frame, point) pair: a missing row is a point not observed in that frame.
Every point must be observed in at least 2 frames and every frame must observe at least 3
points (:func:`moju_core.validation.check_observations`); with ``short_tracks="drop"`` the
points observed in fewer than 2 frames are left out with a warning instead, as the tracks of
a video are (:func:`moju_core.validation.solvable_points`).

Result files hold ``shapes`` (F x P x 3, every point in every frame, the unobserved ones
filled in by the solver), ``visibility`` (F x P bool, the observations used), ``rotations``
(F x 2 x 3), ``labels`` (P,), the per-iteration history, the diagnostics and the metadata;
:func:`read_result` returns the same :class:`~moju_core.result.Result` that
:func:`moju_core.reconstruct` does. Every result is written to a temporary file and renamed
into place, so a crash never leaves a half-written file under the final name.

The package's modules: :mod:`~moju_core.io.measurements` (the validated input),
:mod:`~moju_core.io.input_files` (reading and writing measurement files, with one private
reader per format), :mod:`~moju_core.io.result_files` (result files) and
:mod:`~moju_core.io.atomic` (the atomic write every writer uses). Import the public names from
``moju_core.io``.
"""

from moju_core.io._sources import FORMATS, Admit, PathLike, Source
from moju_core.io.atomic import atomic_output
from moju_core.io.input_files import read_measurements, write_measurements
from moju_core.io.measurements import Measurements
from moju_core.io.result_files import read_result, write_result

__all__ = [
    "FORMATS",
    "Admit",
    "Measurements",
    "PathLike",
    "Source",
    "atomic_output",
    "read_measurements",
    "read_result",
    "write_measurements",
    "write_result",
]
