"""The paper's noise protocol."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def add_noise(W: np.ndarray, noise: float, seed: int = 0) -> np.ndarray:
    """Add Gaussian noise of standard deviation ``noise * max|W|`` (the paper's protocol).

    Parameters
    ----------
    W : ndarray of shape (2F, P), float64
        Image tracks.
    noise : float
        Relative level ``lambda_g`` (the paper uses 0.01 to 0.055); 0 returns a copy.
    seed : int, default 0
        Seed of the noise.

    Returns
    -------
    noisy : ndarray of shape (2F, P), float64
        A new array; ``W`` is not modified.
    """
    W = np.asarray(W, dtype=np.float64)
    if not np.isfinite(noise) or noise < 0:
        raise ValueError(f"noise must be a finite number >= 0, got {noise!r}")
    if noise == 0:
        return W.copy()
    scale = noise * np.max(np.abs(W))
    return W + np.random.default_rng(seed).normal(scale=scale, size=W.shape)


def perturb_rotations(rotations: np.ndarray, degrees: float, seed: int = 0) -> np.ndarray:
    """Camera rotations each turned by ``degrees`` about its own random axis.

    The errors are independent from frame to frame (the jitter of an imperfect calibration or
    tracker), as used to measure what slightly wrong known cameras cost.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Rotations with orthonormal rows.
    degrees : float
        Angle of every frame's error.
    seed : int, default 0
        Seed of the axes.

    Returns
    -------
    ndarray of shape (F, 2, 3)
        ``R_f E_f`` for random rotations ``E_f`` of ``degrees``.
    """
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(len(rotations), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    turn = Rotation.from_rotvec(np.radians(degrees) * axes).as_matrix()
    full = np.concatenate([rotations, np.cross(rotations[:, 0], rotations[:, 1])[:, None]], 1)
    return (full @ turn)[:, :2]
