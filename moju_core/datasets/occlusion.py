"""Visibility masks: a sweeping occluder, lost tracks and random dropout."""

from __future__ import annotations

import numpy as np

from moju_core.datasets.sequence import Sequence


def occlusion_mask(
    sequence: Sequence,
    *,
    band: float = 0.2,
    lost: float = 0.1,
    dropout: float = 0.02,
    seed: int = 0,
) -> np.ndarray:
    """Visibility of a sequence's points under a sweeping occluder, lost tracks and dropout.

    * An occluder band covering ``band`` of the image width (of the tracks' x range) sweeps
      once across the object over the sequence, from a random side; points inside it are
      hidden.
    * ``lost`` of the tracks end at a random frame (uniform over the sequence) and stay lost.
    * ``dropout`` of the remaining entries are hidden at random.
    Every point stays visible in at least two frames and every frame sees at least three
    points (the solver's minimum-observation rules): entries are restored where needed.

    Parameters
    ----------
    sequence : Sequence
    band, lost, dropout : float
        Fractions in [0, 1).
    seed : int

    Returns
    -------
    ndarray of shape (F, P), bool
        True where the point is observed.
    """
    rng = np.random.default_rng(seed)
    n_frames, n_points = sequence.n_frames, sequence.n_points
    x = sequence.W.reshape(n_frames, 2, n_points)[:, 0]
    x = x - x.mean(axis=1, keepdims=True)
    low, high = float(x.min()), float(x.max())
    width = band * (high - low)
    # The band's left edge goes from just outside one side to just outside the other.
    edges = np.linspace(low - width, high, n_frames)
    if rng.random() < 0.5:
        edges = edges[::-1]
    visible = ~((x >= edges[:, None]) & (x < edges[:, None] + width))
    ending = rng.choice(n_points, int(round(lost * n_points)), replace=False)
    last = rng.integers(0, n_frames, size=ending.size)
    frames = np.arange(n_frames)[:, None]
    visible[:, ending] &= frames <= last[None, :]
    visible &= rng.random(visible.shape) >= dropout
    # Minimum observations: two frames per point (the first two), three points per frame.
    for j in np.flatnonzero(visible.sum(axis=0) < 2):
        visible[:2, j] = True
    for f in np.flatnonzero(visible.sum(axis=1) < 3):
        visible[f, rng.choice(n_points, 3, replace=False)] = True
    return visible
