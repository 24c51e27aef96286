"""The paper's noise protocol."""

from __future__ import annotations

import numpy as np


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
