"""Synthetic orthographic sequences of exactly rank 3K, for the camera estimators' tests.

A face-like surface patch (a bump) as the mean shape, K - 1 smooth deformation modes, smooth
coefficients with ``c_f0 = 1``, and smooth camera rotations about all three axes (+-40, +-50
and +-15 degrees about x, y and z).
"""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose


def _axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    """Rotations about one coordinate axis, (F,) radians -> (F, 3, 3)."""
    i, j = [(1, 2), (0, 2), (0, 1)][axis]
    R = np.zeros(angles.shape + (3, 3))
    R[:, axis, axis] = 1.0
    R[:, i, i] = R[:, j, j] = np.cos(angles)
    R[:, i, j] = -np.sin(angles)
    R[:, j, i] = np.sin(angles)
    return R


def make_sequence(
    n_frames: int = 60,
    n_points: int = 500,
    n_bases: int = 3,
    seed: int = 0,
    *,
    noise: float = 0.0,
    amplitude: tuple[float, float] = (0.1, 0.5),
    angles_deg: tuple[float, float, float] = (40.0, 50.0, 15.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Synthetic measurements W (2F, P), true rotations (F, 2, 3) and shapes (F, 3, P).

    ``noise`` is the standard deviation of Gaussian noise as a fraction of ``max|W|`` (the
    project's noise protocol); ``amplitude`` bounds the coefficients of the deformation
    modes; ``angles_deg`` are the amplitudes of the smooth rotations about x, y and z.
    """
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-1.0, 1.0, size=(n_points, 2))
    mean_shape = np.vstack([uv.T, 0.6 * np.exp(-2.0 * (uv**2).sum(axis=1))])
    modes = []
    for _ in range(n_bases - 1):
        # A smooth displacement field: a few low-frequency waves over the surface.
        frequencies = 2.5 * rng.normal(size=(4, 2))
        phases = rng.uniform(0.0, 2.0 * np.pi, size=4)
        modes.append((np.cos(uv @ frequencies.T + phases) @ rng.normal(size=(4, 3))).T)
    bases = [b - b.mean(axis=1, keepdims=True) for b in [mean_shape, *modes]]
    # Make the modes linearly independent of the mean shape and of each other, each with the
    # norm of the mean shape, so that W has rank exactly 3K.
    orthonormal, _ = np.linalg.qr(np.vstack(bases).T)
    scale = np.linalg.norm(bases[0])
    bases = [bases[0]] + [
        scale * orthonormal[:, 3 * k : 3 * k + 3].T / np.sqrt(3.0) for k in range(1, n_bases)
    ]
    t = np.linspace(0.0, 1.0, n_frames)
    coefficients = np.ones((n_frames, n_bases))
    for k in range(1, n_bases):
        coefficients[:, k] = rng.uniform(*amplitude) * np.sin(
            2.0 * np.pi * rng.uniform(0.5, 2.0) * t + rng.uniform(0.0, 2.0 * np.pi)
        )
    shapes = np.einsum("fk,kdp->fdp", coefficients, np.array(bases))
    angles = [
        np.radians(a) * np.sin(2.0 * np.pi * rng.uniform(0.3, 1.2) * t + rng.uniform(0, 2 * np.pi))
        for a in angles_deg
    ]
    R = (
        _axis_rotations(2, angles[2])
        @ _axis_rotations(1, angles[1])
        @ _axis_rotations(0, angles[0])
    )
    R = R[:, :2, :]
    W = np.einsum("fij,fjp->fip", R, shapes).reshape(2 * n_frames, n_points)
    if noise:
        W = W + noise * np.abs(W).max() * rng.normal(size=W.shape)
    return W - W.mean(axis=1, keepdims=True), R, shapes


def assert_orthonormal_rows(R: np.ndarray, n_frames: int) -> None:
    assert R.shape == (n_frames, 2, 3)
    assert R.dtype == np.float64
    assert_allclose(
        R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(2), (n_frames, 2, 2)), atol=1e-10
    )
