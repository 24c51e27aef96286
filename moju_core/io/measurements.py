"""The validated input of one reconstruction."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from moju_core.validation import (
    check_colors,
    check_faces,
    check_ground_truth,
    check_observations,
    check_rotations,
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
    """

    W: np.ndarray
    rotations: np.ndarray | None = None
    ground_truth: np.ndarray | None = None
    faces: np.ndarray | None = None
    colors: np.ndarray | None = None
    visibility: np.ndarray | None = None

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
