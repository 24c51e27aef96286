"""Isometrically bent sheets seen by a perspective camera, for the surface prior's tests."""

from __future__ import annotations

import numpy as np


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` radians about ``axis`` (Rodrigues)."""
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def cylinder_sheet(
    n_points: int = 80, n_frames: int = 6, seed: int = 0, noise: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """A 2 x 1.4 sheet rolled onto cylinders of changing radius, 3 units away, in perspective.

    Isometric by construction (arc length along the bend is kept). Returns rays (F, P, 2) and
    the true points (F, P, 3).
    """
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.linspace(-1, 1, 10), np.linspace(-0.7, 0.7, 8))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    uv = grid if n_points == grid.shape[0] else rng.uniform([-1, -0.7], [1, 0.7], (n_points, 2))
    truth = np.empty((n_frames, uv.shape[0], 3))
    for f in range(n_frames):
        bend = np.deg2rad(30 + 120 * f / max(n_frames - 1, 1))
        kappa = bend / 2.0
        a, b = uv[:, 0], uv[:, 1]
        local = np.stack([np.sin(kappa * a) / kappa, b, (1 - np.cos(kappa * a)) / kappa], 1)
        local -= local.mean(0)
        pose = _rotation(np.array([0.2, 1.0, 0.1]), np.deg2rad(-10 + 20 * f / n_frames))
        truth[f] = local @ (pose @ _rotation(np.array([1.0, 0.0, 0.0]), 0.4)).T + [0, 0, 3.0]
    rays = truth[..., :2] / truth[..., 2:3] + rng.normal(scale=noise, size=truth[..., :2].shape)
    return rays, truth
