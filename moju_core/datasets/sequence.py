"""A synthetic sequence and its ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Sequence:
    """A synthetic sequence and its ground truth.

    Attributes
    ----------
    name : str
        Sequence name, e.g. ``"face3"``.
    W : ndarray of shape (2F, P), float64
        Image tracks; rows ``2f`` and ``2f + 1`` are x and y of frame f (object units),
        ``W_f = R_f S_f^T + t_f`` plus noise when ``noise > 0``.
    rotations : ndarray of shape (F, 2, 3), float64
        True camera rotations (orthonormal rows).
    shapes : ndarray of shape (F, P, 3), float64
        True 3D shapes in the world frame, each frame centred on its centroid.
    translations : ndarray of shape (F, 2), float64
        Image translations that were added to the projections.
    faces : ndarray of shape (M, 3), int64, or None
        Triangles over the points (indices into P), for mesh export.
    colors : ndarray of shape (P, 3), uint8
        A per-point colour (shading by height or by surface coordinate).
    noise : float, default 0.0
        The noise level ``lambda_g`` that was added to ``W``
        (:func:`moju_core.datasets.add_noise`).
    """

    name: str
    W: np.ndarray
    rotations: np.ndarray
    shapes: np.ndarray
    translations: np.ndarray
    faces: np.ndarray | None
    colors: np.ndarray
    noise: float = 0.0

    def __post_init__(self) -> None:
        n_frames, n_points = self.shapes.shape[:2]
        expected = {
            "W": (self.W.shape, (2 * n_frames, n_points)),
            "rotations": (self.rotations.shape, (n_frames, 2, 3)),
            "shapes": (self.shapes.shape, (n_frames, n_points, 3)),
            "translations": (self.translations.shape, (n_frames, 2)),
            "colors": (self.colors.shape, (n_points, 3)),
        }
        for field_name, (actual, wanted) in expected.items():
            if actual != wanted:
                raise ValueError(f"{field_name} must have shape {wanted}, got {actual}")
        if self.faces is not None and (self.faces.ndim != 2 or self.faces.shape[1] != 3):
            raise ValueError(f"faces must have shape (M, 3), got {self.faces.shape}")

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.shapes.shape[0])

    @property
    def n_points(self) -> int:
        """Number of tracked points P."""
        return int(self.shapes.shape[1])

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The sequence under the dataset names of the project's input file contract.

        Returns
        -------
        arrays : dict of str to ndarray
            ``W`` (2F, P), ``R`` (F, 2, 3), ``gt`` (F, P, 3), ``colors`` (P, 3) and, when
            there is a mesh, ``faces`` (M, 3).
        """
        arrays = {"W": self.W, "R": self.rotations, "gt": self.shapes, "colors": self.colors}
        if self.faces is not None:
            arrays["faces"] = self.faces
        return arrays
