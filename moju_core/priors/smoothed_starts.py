"""Other starts for the consistency rounds: the plain program's depths, smoothed per image.

The consistency rounds of :mod:`~moju_core.priors.cone_program` are a local method: they stop
at a stationary point near the depths they start from, and the plain maximum-depth solution,
their usual start, carries the heuristic's extra relief between neighbours. Smoothing that
solution in each image gives starts from other basins, from the tracks alone:

* :func:`bent_depths`: the polynomial of degree 2 in ``(x', y')`` closest to the inverse
  depths (a plane and one bend; the inverse depth of a plane is linear in ``(x', y')``);
* :func:`local_plane_depths`: each inverse depth replaced by the weighted local plane through
  its ``m`` nearest points, the dense stage's interpolation
  (:func:`~moju_core.priors.dense_depth.interpolate_depths`).

Only the directions of the edges in the start matter to the rounds (their lower bounds are
linearised around them), so the starts need no common scale.
"""

from __future__ import annotations

import numpy as np

from moju_core.priors.dense_depth import interpolate_depths

__all__ = ["bent_depths", "local_plane_depths", "smoothed_start_depths"]


def smoothed_start_depths(rays: np.ndarray, depths: np.ndarray) -> list[np.ndarray]:
    """The starts (each (F, P)) made from ``depths`` (F, P; NaN where unknown) seen along
    ``rays`` (F, P, 2): :func:`bent_depths`, then :func:`local_plane_depths`.

    Cost: ``O(F P (m + log P))``.
    """
    return [bent_depths(rays, depths), local_plane_depths(rays, depths)]


def bent_depths(rays: np.ndarray, depths: np.ndarray) -> np.ndarray:
    """Per image, the depths whose inverse is the polynomial of degree 2 in ``(x', y')``
    closest (least squares) to ``1 / depths``.

    ``rays`` (F, P, 2) normalised image coordinates, ``depths`` (F, P) positive or NaN.
    Returns (F, P): NaN stays NaN, and an image with fewer depths than the 6 coefficients
    keeps its own. Cost ``O(F P)``.
    """
    out = np.array(depths, dtype=np.float64)
    x, y = rays[..., 0], rays[..., 1]
    basis = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)
    for f, row in enumerate(depths):
        known = np.isfinite(row)
        if known.sum() < basis.shape[-1]:
            continue
        fit = np.linalg.lstsq(basis[f, known], 1.0 / row[known], rcond=None)[0]
        # A fit that crosses zero inverse depth (a point at infinity) is clipped far away.
        out[f, known] = 1.0 / np.maximum(basis[f, known] @ fit, 1e-3 / row[known].max())
    return out


def local_plane_depths(rays: np.ndarray, depths: np.ndarray, m: int = 8) -> np.ndarray:
    """Each depth of ``depths`` (F, P) replaced by the local plane fit of
    :func:`~moju_core.priors.dense_depth.interpolate_depths` through the inverse depths of
    its ``m`` nearest points in the image (its own included), as if it were not an anchor.

    ``rays`` (F, P, 2). Returns (F, P), NaN where ``depths`` is NaN. Cost
    ``O(F P (m + log P))``.
    """
    out = np.full(depths.shape, np.nan)
    for f, row in enumerate(depths):
        known = np.flatnonzero(np.isfinite(row))
        if known.size == 0:
            continue
        # Every point is a target, and the anchors are copies of the points 1e-9 away: each
        # point's fit includes its own depth, and no point keeps it as an anchor would.
        shifted = np.concatenate([rays[f : f + 1], rays[f : f + 1, known] + 1e-9], axis=1)
        targets = np.zeros((1, row.size + known.size), dtype=bool)
        targets[0, known] = True
        anchors = row.size + np.arange(known.size)
        fitted = interpolate_depths(shifted, targets, anchors, row[None, known], m=m)
        out[f, known] = fitted[0, known]
    return out
