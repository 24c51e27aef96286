"""Checks of everything a user hands to MoJu: tracks, rotations, ground truth, faces, colours.

The library, the CLI, the HTTP API (uploads from strangers) and the worker all validate through
these functions, so a bad input gets the same message everywhere. Every failure raises
:class:`moju_core.errors.MeasurementError` whose message says what is wrong and how to fix it.
Each ``check_*`` function returns the array converted to the dtype the rest of the code expects.
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import ArrayLike

from moju_core.errors import MeasurementError

__all__ = [
    "W_to_tracks",
    "check_colors",
    "check_dtype",
    "check_faces",
    "check_ground_truth",
    "check_measurements",
    "check_observation_counts",
    "check_observations",
    "check_rotations",
    "check_visibility",
    "solvable_points",
    "tracks_to_W",
    "warn_if_transposed",
    "with_missing",
]

#: Largest deviation of ``R_f R_f^T`` from the identity accepted by :func:`check_rotations`.
ROTATION_TOLERANCE = 1e-6

_KIND_NAMES = {
    "b": "booleans",
    "c": "complex numbers",
    "f": "floating-point numbers",
    "S": "byte strings",
    "U": "strings",
    "V": "compound or raw records",
    "M": "dates",
    "m": "time differences",
}

_W_LAYOUT = "rows 2f, 2f+1 are x, y of frame f"


def _as_array(name: str, value: ArrayLike) -> np.ndarray:
    """``np.asarray`` that turns numpy's complaint about ragged input into a clear error."""
    try:
        return np.asarray(value)
    except (ValueError, TypeError) as exc:
        raise MeasurementError(
            f"{name} is not a rectangular array ({exc}); pass a numeric array in which every row "
            "has the same length"
        ) from exc


def check_dtype(name: str, dtype: np.dtype | type | str, *, integer: bool = False) -> None:
    """Refuse a dtype that is not a real number (or an integer when ``integer`` is set).

    Used on arrays and on dtypes declared by file headers before any data is read.

    Parameters
    ----------
    name : str
        Name of the array, used in the message.
    dtype : numpy dtype or anything ``np.dtype`` accepts
        The dtype to check.
    integer : bool, default False
        Require an integer dtype (signed or unsigned) instead of any real dtype.

    Raises
    ------
    MeasurementError
        For object, string, boolean, complex, compound or date dtypes, and for floating dtypes
        when ``integer`` is set.
    """
    dtype = np.dtype(dtype)
    if dtype.hasobject:
        raise MeasurementError(
            f"{name} holds Python objects or variable-length data (dtype {dtype}); MoJu reads "
            f"only plain rectangular numeric arrays (never pickles): store {name} as a float or "
            "integer array"
        )
    allowed = "iu" if integer else "fiu"
    if dtype.kind in allowed:
        return
    found = _KIND_NAMES.get(dtype.kind, "values of an unsupported type")
    if integer and dtype.kind == "f":
        hint = f"; if they are whole numbers convert them with {name}.astype(np.int64)"
    else:
        hint = ""
    needed = "integers" if integer else "real numbers (float or integer)"
    raise MeasurementError(f"{name} holds {found} (dtype {dtype}); it needs {needed}{hint}")


def _first_non_finite(array: np.ndarray) -> tuple[int, int, tuple[int, ...]] | None:
    """Count NaN and infinite entries and locate the first one in C order; None if all finite."""
    finite = np.isfinite(array)
    if finite.all():
        return None
    n_nan = int(np.count_nonzero(np.isnan(array)))
    n_inf = int(array.size - np.count_nonzero(finite)) - n_nan
    first = np.unravel_index(int(np.argmin(finite.ravel())), array.shape)
    return n_nan, n_inf, tuple(int(i) for i in first)


#: Fewest frames in which every point must be observed: depth comes from seeing a point move.
MIN_FRAMES_PER_POINT = 2
#: Fewest points every frame must observe: an orthographic camera (rotation and image
#: translation) is pinned down by three non-collinear points, the same minimum as the number
#: of points of complete data.
MIN_POINTS_PER_FRAME = 3
#: Most frame or point numbers quoted in one message.
_QUOTED = 8


def _check_layout(W: ArrayLike, min_frames: int, min_points: int) -> np.ndarray:
    """Shape and dtype checks shared by :func:`check_measurements` and
    :func:`check_observations`; returns W as C-contiguous float64 (NaN and inf kept)."""
    W = _as_array("W", W)
    check_dtype("W", W.dtype)
    if W.ndim != 2:
        raise MeasurementError(
            f"W has shape {W.shape} ({W.ndim}-D); it needs 2 dimensions, shape (2F, P) with "
            f"{_W_LAYOUT}. Tracks of shape (F, P, 2) convert with tracks_to_W"
        )
    n_rows, n_points = W.shape
    if n_rows % 2:
        raise MeasurementError(
            f"W has {n_rows} rows; it needs an even number ({_W_LAYOUT}). If W is stored "
            "transposed (P x 2F), transpose it"
        )
    n_frames = n_rows // 2
    if n_frames < min_frames:
        raise MeasurementError(
            f"W has {n_frames} frame(s) ({n_rows} rows); at least {min_frames} frames are "
            "needed, because depth comes from seeing the object from several views"
        )
    if n_points < min_points:
        raise MeasurementError(
            f"W has {n_points} point(s) (columns); at least {min_points} are needed"
        )
    # A long double beyond float64's range becomes inf here, which the callers report.
    with np.errstate(over="ignore"):
        return np.ascontiguousarray(W, dtype=np.float64)


def check_measurements(W: ArrayLike, *, min_frames: int = 2, min_points: int = 3) -> np.ndarray:
    """Check a complete measurement matrix (every point in every frame), return it as float64.

    Measurements with unobserved entries are checked by :func:`check_observations`; on
    complete data both return the same array.

    Parameters
    ----------
    W : array_like of shape (2F, P)
        Image coordinates in pixels (or any unit): rows ``2f`` and ``2f+1`` are the x and y
        of frame ``f``, column ``j`` is point ``j``. Integer and float dtypes are accepted.
    min_frames : int, default 2
        Smallest number of frames F accepted.
    min_points : int, default 3
        Smallest number of points P accepted.

    Returns
    -------
    W : ndarray of shape (2F, P), float64, C-contiguous
        The input itself when it already has that layout, otherwise a converted copy.

    Raises
    ------
    MeasurementError
        When W is not 2-D, not real-valued, has an odd number of rows, too few frames or
        points, or holds NaN or infinite values.
    """
    W = _check_layout(W, min_frames, min_points)
    bad = _first_non_finite(W)
    if bad is not None:
        n_nan, n_inf, (row, column) = bad
        coordinate = "xy"[row % 2]
        raise MeasurementError(
            f"W holds {n_nan} NaN and {n_inf} infinite value(s); the first is {coordinate} of "
            f"frame {row // 2}, point {column} (row {row}, column {column}). Every point must be "
            "tracked in every frame here; use check_observations for measurements in which "
            "unobserved points are NaN (x and y both)"
        )
    return W


def _quoted(indices: np.ndarray) -> str:
    shown = ", ".join(str(int(i)) for i in indices[:_QUOTED])
    return shown + (", ..." if indices.size > _QUOTED else "")


def check_visibility(visibility: ArrayLike, n_frames: int, n_points: int) -> np.ndarray:
    """Check a visibility mask and return it as C-contiguous bool.

    Parameters
    ----------
    visibility : array_like of shape (F, P), bool (or integers 0 and 1)
        ``visibility[f, j]`` is True when point ``j`` is observed in frame ``f``.
    n_frames, n_points : int
        F and P of the measurements.

    Returns
    -------
    visibility : ndarray of shape (F, P), bool, C-contiguous
    """
    visibility = _as_array("visibility", visibility)
    kind = visibility.dtype.kind
    if kind != "b":
        check_dtype("visibility", visibility.dtype, integer=True)
    if visibility.shape != (n_frames, n_points):
        raise MeasurementError(
            f"visibility has shape {visibility.shape}; it needs ({n_frames}, {n_points}): one "
            "flag per frame and point, True where the point is observed"
        )
    if kind != "b":
        if visibility.size and (visibility.min() < 0 or visibility.max() > 1):
            raise MeasurementError(
                f"visibility holds values from {visibility.min()} to {visibility.max()}; it "
                "needs booleans (or 0 and 1): True where the point is observed"
            )
    return np.ascontiguousarray(visibility, dtype=bool)


def _visibility_of(W: np.ndarray, visibility: ArrayLike | None) -> np.ndarray:
    """The (F, P) mask of W's finite entries, checked against ``visibility`` when given."""
    n_frames, n_points = W.shape[0] // 2, W.shape[1]
    bad = _first_non_finite(W)
    if bad is not None and bad[1]:
        n_inf = bad[1]
        row, column = (int(i) for i in np.argwhere(np.isinf(W))[0])
        raise MeasurementError(
            f"W holds {n_inf} infinite value(s); the first is {'xy'[row % 2]} of frame "
            f"{row // 2}, point {column} (row {row}, column {column}). Mark a point that is not "
            "observed in a frame with NaN (x and y both), never with inf"
        )
    finite = np.isfinite(W).reshape(n_frames, 2, n_points)
    observed = finite[:, 0] & finite[:, 1]
    half = finite[:, 0] != finite[:, 1]
    if half.any():
        frame, point = (int(i) for i in np.argwhere(half)[0])
        nan, other = ("y", "x") if finite[frame, 0, point] else ("x", "y")
        raise MeasurementError(
            f"W holds {int(half.sum())} (frame, point) entries with one coordinate NaN and the "
            f"other not; the first is {nan} of frame {frame}, point {point} (NaN while its "
            f"{other} is not). A point that is not observed in a frame has x and y both NaN: "
            "set both, or neither"
        )
    if visibility is None:
        return observed
    visibility = check_visibility(visibility, n_frames, n_points)
    disagree = visibility != observed
    if disagree.any():
        frame, point = (int(i) for i in np.argwhere(disagree)[0])
        if visibility[frame, point]:
            what = "visibility says it is observed but W holds NaN there"
        else:
            what = "visibility says it is not observed but W holds a value there"
        raise MeasurementError(
            f"W and visibility disagree at {int(disagree.sum())} (frame, point) entries; the "
            f"first is frame {frame}, point {point}: {what}. W must be NaN exactly where "
            "visibility is False, e.g. W[np.repeat(~visibility, 2, axis=0)] = np.nan, or leave "
            "visibility out and mark the unobserved entries of W with NaN"
        )
    return visibility


def check_observation_counts(frames_per_point: np.ndarray, points_per_frame: np.ndarray) -> None:
    """Refuse points seen in too few frames and frames that see too few points.

    Parameters
    ----------
    frames_per_point : ndarray of shape (P,), int
        In how many frames each point is observed.
    points_per_frame : ndarray of shape (F,), int
        How many points each frame observes.

    Raises
    ------
    MeasurementError
        When a point is observed in fewer than :data:`MIN_FRAMES_PER_POINT` frames or a frame
        observes fewer than :data:`MIN_POINTS_PER_FRAME` points; the message names them.
    """
    frames_per_point = np.asarray(frames_per_point)
    points_per_frame = np.asarray(points_per_frame)
    thin_points = np.flatnonzero(frames_per_point < MIN_FRAMES_PER_POINT)
    if thin_points.size:
        raise MeasurementError(
            f"{thin_points.size} point(s) are observed (not NaN) in fewer than "
            f"{MIN_FRAMES_PER_POINT} frames: point(s) {_quoted(thin_points)}. A point's depth "
            "comes from seeing it in several frames: drop these points (columns of W), e.g. "
            f"keep = visibility.sum(axis=0) >= {MIN_FRAMES_PER_POINT}; W = W[:, keep]"
        )
    thin_frames = np.flatnonzero(points_per_frame < MIN_POINTS_PER_FRAME)
    if thin_frames.size:
        counts = _quoted(points_per_frame[thin_frames])
        raise MeasurementError(
            f"{thin_frames.size} frame(s) observe (not NaN) fewer than {MIN_POINTS_PER_FRAME} "
            f"points: frame(s) {_quoted(thin_frames)}, with {counts} observed point(s). A "
            f"frame's camera needs at least {MIN_POINTS_PER_FRAME} observed points: drop these "
            "frames (rows 2f and 2f+1 of W, and row f of visibility) or track more points in them"
        )


def check_observations(
    W: ArrayLike,
    visibility: ArrayLike | None = None,
    *,
    min_frames: int = 2,
    min_points: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Check measurements that may miss points in some frames.

    A point that is not observed in a frame has NaN as both its x and its y there. The mask
    ``visibility`` may be given as well; it must then agree with W. Every point must be
    observed in at least :data:`MIN_FRAMES_PER_POINT` (2) frames and every frame must observe
    at least :data:`MIN_POINTS_PER_FRAME` (3) points. Infinite values are always refused.

    Parameters
    ----------
    W : array_like of shape (2F, P)
        Image coordinates, rows ``2f`` and ``2f+1`` are x and y of frame ``f``; NaN (x and y
        together) where a point is not observed.
    visibility : array_like of shape (F, P), bool, optional
        True where point ``j`` is observed in frame ``f``. When given, W must be NaN exactly
        where it is False.
    min_frames, min_points : int
        Smallest F and P accepted, as in :func:`check_measurements`.

    Returns
    -------
    W : ndarray of shape (2F, P), float64, C-contiguous
        W with 0.0 at the unobserved entries. For complete data it is exactly what
        :func:`check_measurements` returns (the input itself when it already is C-contiguous
        float64); otherwise a new array (the input is never modified).
    visibility : ndarray of shape (F, P), bool
        True where the point is observed (all True for complete data).

    Raises
    ------
    MeasurementError
        For everything :func:`check_measurements` refuses except NaN, and for a NaN in only
        one coordinate, a visibility that disagrees with W, a point observed in fewer than 2
        frames or a frame observing fewer than 3 points.
    """
    W = _check_layout(W, min_frames, min_points)
    observed = _visibility_of(W, visibility)
    if observed.all():
        return W, observed
    check_observation_counts(np.count_nonzero(observed, axis=0), np.count_nonzero(observed, axis=1))
    return np.where(np.repeat(observed, 2, axis=0), W, 0.0), observed


def solvable_points(W: ArrayLike, visibility: ArrayLike | None = None) -> np.ndarray:
    """Which points the solver can use: those observed in at least
    :data:`MIN_FRAMES_PER_POINT` frames; warns with how many are left out.

    The one rule for tracks seen in one frame only (a point seen once gives no depth), shared
    by the tracks of a video (:func:`moju_core.footage.tracking.solvable_tracks`) and a tracks
    file read with ``short_tracks="drop"`` (:func:`moju_core.io.read_measurements`).

    Parameters
    ----------
    W : array_like of shape (2F, P)
        Image coordinates (rows ``2f``, ``2f+1`` are x, y of frame ``f``); NaN where a point
        is not observed.
    visibility : array_like of shape (F, P), bool, optional
        When given, it must agree with the NaN of W (as in :func:`check_observations`).

    Returns
    -------
    keep : ndarray of shape (P,), bool
        True for the points to keep.

    Warns
    -----
    UserWarning
        When some points are left out: how many, of how many.

    Raises
    ------
    MeasurementError
        For what :func:`check_observations` refuses in W and visibility themselves (layout,
        dtype, infinite values, NaN in one coordinate, a disagreeing visibility).
    """
    W = _check_layout(W, 2, 1)
    observed = _visibility_of(W, visibility)
    keep = np.count_nonzero(observed, axis=0) >= MIN_FRAMES_PER_POINT
    dropped = int(keep.size - np.count_nonzero(keep))
    if dropped:
        warnings.warn(
            f"{dropped} of {keep.size} tracks are seen in fewer than {MIN_FRAMES_PER_POINT} "
            f"frames (a point seen once gives no depth) and are left out; "
            f"{keep.size - dropped} are kept",
            UserWarning,
            stacklevel=2,
        )
    return keep


def with_missing(W: ArrayLike, visibility: ArrayLike) -> np.ndarray:
    """W with NaN (x and y) at the entries that ``visibility`` marks as not observed.

    Parameters
    ----------
    W : array_like of shape (2F, P)
        Measurements (any value at the unobserved entries).
    visibility : array_like of shape (F, P), bool
        True where the point is observed.

    Returns
    -------
    ndarray of shape (2F, P), float64
        A new array; the input is not modified.
    """
    W = np.array(W, dtype=np.float64)
    mask = np.asarray(visibility, dtype=bool)
    if W.ndim != 2 or mask.shape != (W.shape[0] // 2, W.shape[1]) or W.shape[0] % 2:
        raise MeasurementError(
            f"W {W.shape} and visibility {mask.shape} do not fit: they need shapes (2F, P) "
            "and (F, P)"
        )
    W[np.repeat(~mask, 2, axis=0)] = np.nan
    return W


def tracks_to_W(tracks: ArrayLike) -> np.ndarray:
    """Stack per-frame tracks into the measurement matrix.

    Only the layout is checked here; run :func:`check_measurements` on the result.

    Parameters
    ----------
    tracks : array_like of shape (F, P, 2)
        ``tracks[f, j]`` is the (x, y) image position of point ``j`` in frame ``f``.

    Returns
    -------
    W : ndarray of shape (2F, P)
        Rows ``2f`` and ``2f+1`` are x and y of frame ``f``; same dtype as ``tracks``.
    """
    tracks = _as_array("tracks", tracks)
    if tracks.ndim != 3 or tracks.shape[2] != 2:
        raise MeasurementError(
            f"tracks has shape {tracks.shape}; it needs shape (F, P, 2): the (x, y) position of "
            "every point in every frame"
        )
    n_frames, n_points, _ = tracks.shape
    return tracks.transpose(0, 2, 1).reshape(2 * n_frames, n_points)


def W_to_tracks(W: ArrayLike) -> np.ndarray:
    """Inverse of :func:`tracks_to_W`.

    Parameters
    ----------
    W : array_like of shape (2F, P)
        Measurement matrix, rows ``2f`` and ``2f+1`` are x and y of frame ``f``.

    Returns
    -------
    tracks : ndarray of shape (F, P, 2)
        ``tracks[f, j]`` is the (x, y) position of point ``j`` in frame ``f``.
    """
    W = _as_array("W", W)
    if W.ndim != 2 or W.shape[0] % 2:
        raise MeasurementError(
            f"W has shape {W.shape}; it needs shape (2F, P) with an even number of rows "
            f"({_W_LAYOUT})"
        )
    n_rows, n_points = W.shape
    return W.reshape(n_rows // 2, 2, n_points).transpose(0, 2, 1)


def _check_finite(name: str, array: np.ndarray, what: str) -> None:
    bad = _first_non_finite(array)
    if bad is not None:
        n_nan, n_inf, index = bad
        raise MeasurementError(
            f"{name} holds {n_nan} NaN and {n_inf} infinite value(s); the first is at index "
            f"{index} ({what} {index[0]}); every value must be finite"
        )


def check_rotations(R: ArrayLike, n_frames: int) -> np.ndarray:
    """Check per-frame camera rotations.

    Parameters
    ----------
    R : array_like of shape (F, 2, 3)
        ``R[f]`` is the orthographic camera of frame ``f``: two orthonormal rows.
    n_frames : int
        Number of frames F of the measurements.

    Returns
    -------
    R : ndarray of shape (F, 2, 3), float64, C-contiguous

    Raises
    ------
    MeasurementError
        On a wrong shape or dtype, non-finite values, or a frame whose rows are not
        orthonormal within ``ROTATION_TOLERANCE`` (max abs entry of ``R_f R_f^T - I``).
    """
    R = _as_array("R", R)
    check_dtype("R", R.dtype)
    if R.shape != (n_frames, 2, 3):
        hint = ""
        if R.shape == (2 * n_frames, 3):
            hint = "; a stacked (2F, 3) matrix converts with R.reshape(-1, 2, 3)"
        raise MeasurementError(
            f"R has shape {R.shape}; it needs ({n_frames}, 2, 3): one 2x3 camera rotation with "
            f"orthonormal rows per frame{hint}"
        )
    R = np.ascontiguousarray(R, dtype=np.float64)
    _check_finite("R", R, "frame")
    deviation = np.abs(R @ R.transpose(0, 2, 1) - np.eye(2)).max(axis=(1, 2))
    failing = np.flatnonzero(deviation > ROTATION_TOLERANCE)
    if failing.size:
        frame = int(failing[0])
        raise MeasurementError(
            f"R of frame {frame} does not have orthonormal rows: max |R_f R_f^T - I| = "
            f"{deviation[frame]:.3g} (tolerance {ROTATION_TOLERANCE:g}); {failing.size} frame(s) "
            "fail. Orthonormalise each 2x3 block, e.g. U @ Vt from its SVD"
        )
    return R


def check_ground_truth(gt: ArrayLike, n_frames: int, n_points: int) -> np.ndarray:
    """Check ground-truth 3D shapes.

    Parameters
    ----------
    gt : array_like of shape (F, P, 3)
        ``gt[f, j]`` is the 3D position of point ``j`` in frame ``f`` (same units as W).
    n_frames, n_points : int
        F and P of the measurements.

    Returns
    -------
    gt : ndarray of shape (F, P, 3), float64, C-contiguous
    """
    gt = _as_array("gt", gt)
    check_dtype("gt", gt.dtype)
    if gt.shape != (n_frames, n_points, 3):
        hint = ""
        if gt.shape == (3 * n_frames, n_points):
            hint = "; a stacked (3F, P) matrix converts with gt.reshape(F, 3, P).transpose(0, 2, 1)"
        raise MeasurementError(
            f"gt has shape {gt.shape}; it needs ({n_frames}, {n_points}, 3): the 3D position of "
            f"every point in every frame{hint}"
        )
    gt = np.ascontiguousarray(gt, dtype=np.float64)
    _check_finite("gt", gt, "frame")
    return gt


def check_faces(faces: ArrayLike, n_points: int) -> np.ndarray:
    """Check triangle indices into the points.

    Parameters
    ----------
    faces : array_like of shape (M, 3), integer
        Each row holds the indices (0-based) of the three points of one triangle.
    n_points : int
        Number of points P.

    Returns
    -------
    faces : ndarray of shape (M, 3), int64, C-contiguous
    """
    faces = _as_array("faces", faces)
    check_dtype("faces", faces.dtype, integer=True)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeasurementError(
            f"faces has shape {faces.shape}; it needs shape (M, 3): three point indices per "
            "triangle"
        )
    # uint64 values above 2**63 would wrap in int64; compare in the input dtype first.
    if faces.size and (faces.min() < 0 or faces.max() >= n_points):
        outside = (faces < 0) | (faces >= n_points)
        face = int(np.flatnonzero(outside.any(axis=1))[0])
        hint = ""
        if faces.min() >= 1 and faces.max() == n_points:
            hint = "; the indices look 1-based, subtract 1"
        raise MeasurementError(
            f"faces holds point indices outside 0..{n_points - 1} (P = {n_points}); the first "
            f"is triangle {face}: {faces[face].tolist()}{hint}"
        )
    return np.ascontiguousarray(faces, dtype=np.int64)


def check_colors(colors: ArrayLike, n_points: int) -> np.ndarray:
    """Check per-point colours.

    Parameters
    ----------
    colors : array_like of shape (P, 3) or (P, 4), integer
        RGB (or RGBA) of every point, each channel in 0..255.
    n_points : int
        Number of points P.

    Returns
    -------
    colors : ndarray of shape (P, 3) or (P, 4), uint8, C-contiguous
    """
    colors = _as_array("colors", colors)
    if colors.dtype.kind == "f":
        raise MeasurementError(
            f"colors holds floating-point numbers (dtype {colors.dtype}); it needs integers in "
            "0..255. Colours in 0..1 convert with np.round(colors * 255).astype(np.uint8)"
        )
    check_dtype("colors", colors.dtype, integer=True)
    if colors.ndim != 2 or colors.shape[0] != n_points or colors.shape[1] not in (3, 4):
        raise MeasurementError(
            f"colors has shape {colors.shape}; it needs ({n_points}, 3) (RGB) or "
            f"({n_points}, 4) (RGBA): one colour per point"
        )
    if colors.size and (colors.min() < 0 or colors.max() > 255):
        raise MeasurementError(
            f"colors holds values from {colors.min()} to {colors.max()}; every channel must be "
            "in 0..255"
        )
    return np.ascontiguousarray(colors, dtype=np.uint8)


#: More frames than this many times the points reads like a transposed W (P x 2F): dense
#: tracks have far more points than frames.
TRANSPOSED_RATIO = 10


def warn_if_transposed(n_frames: int, n_points: int) -> None:
    """Warn when W's layout reads like a transposed W (P x 2F): far more frames than points."""
    if n_frames > TRANSPOSED_RATIO * n_points:
        warnings.warn(
            f"W has {2 * n_frames} rows and {n_points} columns, so it is read as {n_frames} "
            f"frames of {n_points} points; dense tracks have far more points than frames. If "
            f"the rows are the points (W of shape (P, 2F)), pass W.T",
            UserWarning,
            stacklevel=5,
        )
