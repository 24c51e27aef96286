"""Plot-ready views of a reconstruction, for the result viewer (presentation, not solving).

The viewer (the service's web page and the standalone file of ``moju view``) shows one frame
at a time as a 3D point cloud, or as a mesh when triangles were uploaded, coloured by local
group label, by depth or by the uploaded colours, next to the convergence history. When points
were missing from the input, each frame lists which of its shown points the solver filled in
(not observed in that frame), so that the viewer can draw them apart. This module turns a
result into the JSON documents the viewer draws; it knows nothing of HTTP or HTML.

Browsers slow down beyond a few tens of thousands of 3D markers, so a result with more than
``max_points`` points is shown through a subset of its points: a fixed random sample
(:func:`shown_points`), the same in every frame and in every request, so that frames fetched
one at a time line up.

Coordinates are rounded to :data:`RELATIVE_PRECISION` of the frame's largest absolute
coordinate (0.1 pixel on a 1000-pixel view), which keeps the JSON small.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import h5py
import numpy as np

from moju_core import file_types
from moju_core.io import read_result
from moju_core.result import Result

__all__ = [
    "DEFAULT_MAX_POINTS",
    "RELATIVE_PRECISION",
    "ResultView",
    "camera_depth",
    "frame_data",
    "open_result",
    "shown_points",
    "summary",
    "viewer_document",
]

#: Most points drawn per frame unless the caller asks for fewer.
DEFAULT_MAX_POINTS = 20_000
#: Seed of the random subset of shown points: fixed, so that every request agrees.
SUBSET_SEED = 0
#: Coordinates are rounded to this fraction of the frame's largest absolute coordinate.
RELATIVE_PRECISION = 1e-4


class FrameStack(Protocol):
    """The per-frame shapes, (F, P, 3): an ndarray or an open HDF5 dataset."""

    shape: tuple[int, ...]

    def __getitem__(self, index: int) -> np.ndarray: ...


@dataclass(frozen=True)
class ResultView:
    """What the viewer needs of a result; ``shapes`` may stay on disk (an HDF5 dataset).

    Attributes
    ----------
    shapes : array-like of shape (F, P, 3)
        Per-frame 3D points; ``shapes[f]`` reads one frame.
    rotations : ndarray of shape (F, 2, 3)
        Per-frame camera rotations (rows r1, r2).
    labels : ndarray of shape (P,)
        Local group of every point.
    history : dict of str to ndarray of shape (n_iter,)
        Convergence history of the ADMM loop (``gap``, ``rho``, ...).
    n_iter : int
        Iterations run.
    stop_reason : str
        Why the loop stopped.
    visibility : array-like of shape (F, P), bool, or None
        True where a point was observed; ``visibility[f]`` reads one frame. None when the
        result does not say (every point is then shown as observed).
    """

    shapes: FrameStack
    rotations: np.ndarray
    labels: np.ndarray
    history: Mapping[str, np.ndarray] = field(default_factory=dict)
    n_iter: int = 0
    stop_reason: str = ""
    visibility: FrameStack | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.shapes.shape[0])

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return int(self.shapes.shape[1])

    @classmethod
    def of(cls, result: Result) -> ResultView:
        """The view of an in-memory :class:`moju_core.result.Result` (solved or read from a
        file)."""
        return cls(
            shapes=np.asarray(result.shapes),
            rotations=np.asarray(result.rotations),
            labels=np.asarray(result.labels),
            history=dict(result.history),
            n_iter=int(result.n_iter),
            stop_reason=str(result.stop_reason),
            visibility=result.visibility,
        )

    def observed(self, frame: int) -> np.ndarray:
        """(P,) bool: which points frame ``frame`` observed (all True without a visibility)."""
        if self.visibility is None:
            return np.ones(self.n_points, dtype=bool)
        return np.asarray(self.visibility[frame], dtype=bool)


@contextlib.contextmanager
def open_result(path: str | Path) -> Iterator[ResultView]:
    """Open a result file of :func:`moju_core.io.write_result` for viewing.

    An HDF5 result is read lazily: only the frames asked for are read from disk (the layout is
    the one documented in :func:`moju_core.io.write_result`). An npz result is read whole.

    Parameters
    ----------
    path : str or os.PathLike
        The result file (HDF5 or npz, told by its first bytes).

    Raises
    ------
    ValueError
        When the file is not a readable result.
    """
    path = Path(path)
    with open(path, "rb") as handle:
        is_hdf5 = file_types.array_file_type(handle.read(file_types.HEAD_BYTES)) == "h5"
    if not is_hdf5:
        yield ResultView.of(read_result(path))
        return
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path.name} is not a readable MoJu result file ({exc})") from exc
    with h5:
        try:
            group = h5.get("history")
            view = ResultView(
                shapes=h5["shapes"],
                rotations=h5["rotations"][()],
                labels=h5["labels"][()],
                history={key: group[key][()] for key in group} if group is not None else {},
                n_iter=int(h5.attrs["n_iter"]),
                stop_reason=str(h5.attrs["stop_reason"]),
                visibility=h5["visibility"] if "visibility" in h5 else None,
            )
        except KeyError as exc:
            raise ValueError(
                f"{path.name} is not a readable MoJu result file (missing {exc})"
            ) from exc
        yield view


def shown_points(n_points: int, max_points: int = DEFAULT_MAX_POINTS) -> np.ndarray:
    """Indices of the points the viewer draws: all, or a fixed random subset.

    Parameters
    ----------
    n_points : int
        Number of points P of the result.
    max_points : int, default DEFAULT_MAX_POINTS
        Most points to draw.

    Returns
    -------
    ndarray of shape (min(P, max_points),), int64
        Increasing point indices; ``arange(P)`` when nothing needs dropping. The subset depends
        only on ``n_points`` and ``max_points`` (seed :data:`SUBSET_SEED`).
    """
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    if n_points <= max_points:
        return np.arange(n_points, dtype=np.int64)
    chosen = np.random.default_rng(SUBSET_SEED).choice(n_points, size=max_points, replace=False)
    return np.sort(chosen).astype(np.int64)


def camera_depth(points: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Depth of each point along the camera's optical axis.

    Parameters
    ----------
    points : ndarray of shape (n, 3)
        A frame's 3D points.
    rotation : ndarray of shape (2, 3)
        The frame's camera rotation, rows r1 and r2 (image x and y).

    Returns
    -------
    ndarray of shape (n,)
        ``r3 . X`` with ``r3 = r1 x r2``, the third row of the full rotation: the coordinate
        that the orthographic camera drops.
    """
    axis = np.cross(rotation[0], rotation[1])
    return np.asarray(points, dtype=np.float64) @ axis


def _rounded(values: np.ndarray, magnitude: float) -> list[float]:
    """``values`` rounded to RELATIVE_PRECISION of ``magnitude``, as a list of floats."""
    if magnitude > 0 and math.isfinite(magnitude):
        decimals = int(-math.floor(math.log10(magnitude * RELATIVE_PRECISION)))
        values = np.round(values, max(decimals, 0))
    return values.tolist()


def frame_data(view: ResultView, frame: int, indices: np.ndarray) -> dict[str, Any]:
    """One frame's shown points as columns.

    Parameters
    ----------
    view : ResultView
        The result.
    frame : int
        Frame number, 0-based.
    indices : ndarray of int
        Points to include (:func:`shown_points`).

    Returns
    -------
    dict
        ``frame`` and the lists ``x``, ``y``, ``z`` (coordinates in the units of the input)
        and ``depth`` (:func:`camera_depth`), one entry per shown point, rounded to
        :data:`RELATIVE_PRECISION` of the frame's largest absolute coordinate; ``unobserved``:
        the positions (0-based, in the shown points) of the points this frame did not observe,
        i.e. that the solver filled in (empty for complete data).
    """
    if not 0 <= frame < view.n_frames:
        raise IndexError(f"frame {frame} is outside 0..{view.n_frames - 1}")
    points = np.asarray(view.shapes[frame], dtype=np.float64)[indices]
    depth = camera_depth(points, view.rotations[frame])
    magnitude = float(np.abs(points).max()) if points.size else 0.0
    return {
        "frame": int(frame),
        "x": _rounded(points[:, 0], magnitude),
        "y": _rounded(points[:, 1], magnitude),
        "z": _rounded(points[:, 2], magnitude),
        "depth": _rounded(depth, magnitude),
        "unobserved": np.flatnonzero(~view.observed(frame)[indices]).tolist(),
    }


def _hex_colors(colors: np.ndarray) -> list[str]:
    rgb = np.asarray(colors)[:, :3].astype(np.int64)
    return [f"#{r:02x}{g:02x}{b:02x}" for r, g, b in rgb.tolist()]


def _finite_or_none(values: np.ndarray) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, float).tolist()]


def _padded(low: float, high: float) -> list[float]:
    margin = 0.05 * (high - low) or 0.5 * max(abs(low), 1.0)
    return [low - margin, high + margin]


def summary(
    view: ResultView,
    indices: np.ndarray,
    *,
    faces: np.ndarray | None = None,
    colors: np.ndarray | None = None,
) -> dict[str, Any]:
    """Everything the viewer needs besides the frames.

    Parameters
    ----------
    view : ResultView
        The result. Every frame is read once, for the axis ranges.
    indices : ndarray of int
        The shown points (:func:`shown_points`).
    faces : ndarray of shape (M, 3), optional
        Triangles uploaded with the input; kept only when every point is shown (a random
        subset of the points keeps too few whole triangles to draw a surface).
    colors : ndarray of shape (P, 3) or (P, 4), uint8, optional
        Per-point colours uploaded with the input.

    Returns
    -------
    dict
        ``frames``, ``points``, ``shown_points``, ``decimated``, ``point_indices`` (None
        unless decimated), ``labels`` and ``groups`` (distinct labels), ``colors`` (``#rrggbb``
        strings or None), ``faces`` (lists of three shown-point positions, or None), ``ranges``
        (``x``, ``y``, ``z``, ``depth``: [low, high] over every frame, padded by 5 %),
        ``rotations`` (F x 2 x 3, rounded to 1e-6), ``history`` (lists, NaN as None),
        ``n_iter``, ``stop_reason`` and ``observed_fraction`` (of all F x P entries, 1.0 when
        nothing was missing).
    """
    indices = np.asarray(indices, dtype=np.int64)
    decimated = len(indices) < view.n_points
    low = np.full(4, np.inf)
    high = np.full(4, -np.inf)
    n_observed = 0
    for frame in range(view.n_frames):
        n_observed += int(np.count_nonzero(view.observed(frame)))
        points = np.asarray(view.shapes[frame], dtype=np.float64)[indices]
        columns = np.column_stack([points, camera_depth(points, view.rotations[frame])])
        if len(columns):
            low = np.minimum(low, columns.min(axis=0))
            high = np.maximum(high, columns.max(axis=0))
    if not np.isfinite(low).all():  # no points at all
        low, high = np.zeros(4), np.zeros(4)
    labels = np.asarray(view.labels, dtype=np.int64)[indices]
    return {
        "frames": view.n_frames,
        "points": view.n_points,
        "shown_points": int(len(indices)),
        "decimated": bool(decimated),
        "point_indices": indices.tolist() if decimated else None,
        "labels": labels.tolist(),
        "groups": int(len(np.unique(labels))),
        "colors": _hex_colors(np.asarray(colors)[indices]) if colors is not None else None,
        "faces": np.asarray(faces).tolist() if faces is not None and not decimated else None,
        "ranges": {
            axis: _padded(float(low[i]), float(high[i]))
            for i, axis in enumerate(("x", "y", "z", "depth"))
        },
        "rotations": np.round(np.asarray(view.rotations, dtype=np.float64), 6).tolist(),
        "history": {key: _finite_or_none(values) for key, values in view.history.items()},
        "n_iter": int(view.n_iter),
        "stop_reason": view.stop_reason,
        "observed_fraction": n_observed / max(view.n_frames * view.n_points, 1),
    }


def viewer_document(
    view: ResultView,
    *,
    max_points: int = DEFAULT_MAX_POINTS,
    faces: np.ndarray | None = None,
    colors: np.ndarray | None = None,
) -> dict[str, Any]:
    """The summary and every frame in one document, for a self-contained viewer file.

    Parameters
    ----------
    view : ResultView
        The result.
    max_points : int, default DEFAULT_MAX_POINTS
        Most points per frame (:func:`shown_points`).
    faces, colors : ndarray, optional
        As in :func:`summary`.

    Returns
    -------
    dict
        ``{"summary": summary(...), "frames": [frame_data(...), ...]}``.
    """
    indices = shown_points(view.n_points, max_points)
    return {
        "summary": summary(view, indices, faces=faces, colors=colors),
        "frames": [frame_data(view, frame, indices) for frame in range(view.n_frames)],
    }
