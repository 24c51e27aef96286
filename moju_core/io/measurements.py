"""The validated input of one reconstruction."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from moju_core.cameras.intrinsics import Intrinsics, check_frame_size
from moju_core.validation import (
    check_colors,
    check_faces,
    check_ground_truth,
    check_observations,
    check_rotations,
    solvable_points,
)


@dataclass
class Measurements:
    """Validated input of one reconstruction.

    Every field is checked and converted on construction (:mod:`moju_core.validation`).

    Attributes
    ----------
    W : ndarray of shape (2F, P), float64
        Rows ``2f`` and ``2f+1`` are the x and y image coordinates of frame ``f``; NaN (x and
        y) where a point is not observed in a frame.
    visibility : ndarray of shape (F, P), bool, or None
        True where point ``j`` is observed in frame ``f``; None when every point is observed
        in every frame. When given on construction it must agree with the NaN of W; when left
        out it is derived from them.
    rotations : ndarray of shape (F, 2, 3), float64, or None
        Known camera rotations (orthonormal rows).
    ground_truth : ndarray of shape (F, P, 3), float64, or None
        True 3D shapes, for evaluation.
    faces : ndarray of shape (M, 3), int64, or None
        Triangle indices into the points, for mesh export.
    colors : ndarray of shape (P, 3) or (P, 4), uint8, or None
        Per-point RGB (or RGBA) colours, for mesh export.
    intrinsics : Intrinsics or None
        The camera matrix K of the pixels of W (:mod:`moju_core.cameras.intrinsics`). A 3 x 3
        array given on construction becomes an :class:`Intrinsics` with origin ``"given"``.
        None with a ``frame_size``: the default camera of that size (origin ``"default"``).
        None without a ``frame_size``: no camera is known; the tracks are orthographic.
    frame_size : (int, int) or None
        (width, height) of the frames in pixels, when known (tracks of a video).
    """

    W: np.ndarray
    rotations: np.ndarray | None = None
    ground_truth: np.ndarray | None = None
    faces: np.ndarray | None = None
    colors: np.ndarray | None = None
    visibility: np.ndarray | None = None
    intrinsics: Intrinsics | None = None
    frame_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        W, visibility = check_observations(self.W, self.visibility)
        if visibility.all():
            self.W, self.visibility = W, None
        else:  # W is a new array here (zeros filled in): mark the unobserved entries again
            W[np.repeat(~visibility, 2, axis=0)] = np.nan
            self.W, self.visibility = W, visibility
        n_frames, n_points = self.n_frames, self.n_points
        if self.rotations is not None:
            self.rotations = check_rotations(self.rotations, n_frames)
        if self.ground_truth is not None:
            self.ground_truth = check_ground_truth(self.ground_truth, n_frames, n_points)
        if self.faces is not None:
            self.faces = check_faces(self.faces, n_points)
        if self.colors is not None:
            self.colors = check_colors(self.colors, n_points)
        if self.frame_size is not None:
            self.frame_size = check_frame_size(self.frame_size)
        if self.intrinsics is not None and not isinstance(self.intrinsics, Intrinsics):
            self.intrinsics = Intrinsics(self.intrinsics, "given")
        if self.intrinsics is None and self.frame_size is not None:
            self.intrinsics = Intrinsics.default_for(self.frame_size)

    @classmethod
    def of_solvable_points(
        cls,
        W: ArrayLike,
        *,
        visibility: ArrayLike | None = None,
        ground_truth: ArrayLike | None = None,
        faces: ArrayLike | None = None,
        colors: ArrayLike | None = None,
        **fields: Any,
    ) -> Measurements:
        """Measurements of the points the solver can use: points seen in fewer than 2 frames
        are left out, with a warning (:func:`moju_core.validation.solvable_points`).

        Parameters are those of the class. The per-point datasets (ground truth, colours) lose
        the same points; triangles with a left-out corner are dropped and the others renumbered
        (faces None when none is left). Frame-wide fields (rotations, intrinsics, frame size)
        pass through.

        Raises
        ------
        MeasurementError
            For what the class refuses, checked against the points as given.
        """
        keep = solvable_points(W, visibility)
        if keep.all():
            return cls(
                W=W, visibility=visibility, ground_truth=ground_truth, faces=faces,
                colors=colors, **fields,
            )  # fmt: skip
        n_points = keep.size
        W = np.asarray(W)[:, keep]
        if visibility is not None:
            visibility = np.asarray(visibility)[:, keep]
        if ground_truth is not None:
            n_frames = np.asarray(W).shape[0] // 2
            ground_truth = check_ground_truth(ground_truth, n_frames, n_points)[:, keep]
        if colors is not None:
            colors = check_colors(colors, n_points)[keep]
        if faces is not None:
            faces = check_faces(faces, n_points)
            renumber = np.cumsum(keep) - 1
            faces = renumber[faces[keep[faces].all(axis=1)]]
            faces = faces if faces.size else None
        return cls(
            W=W, visibility=visibility, ground_truth=ground_truth, faces=faces, colors=colors,
            **fields,
        )  # fmt: skip

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return self.W.shape[0] // 2

    @property
    def n_points(self) -> int:
        """Number of points P."""
        return self.W.shape[1]

    @property
    def observed_fraction(self) -> float:
        """Fraction of the F x P (frame, point) entries that are observed, in (0, 1]."""
        return 1.0 if self.visibility is None else float(self.visibility.mean())
