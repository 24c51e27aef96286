"""The tracker's last check: a track position must follow its neighbours' motion.

Chained optical flow drifts where the surface turns away from the camera or meets the
silhouette: there the flow is smoothed with what lies beside the object, the forward and
backward flows agree on the wrong motion, and a track slides by a fraction of a pixel per
frame until the forward-backward check finally stops it, several pixels off. The last
frames before a track is lost are its worst. On rendered footage 1-3 % of the tracks err by
more than 2 px in some frame, and those few entries cost more depth accuracy than the rest
of the tracking error together.

Over a small patch the image motion of a smooth surface is close to affine, so each track
position is compared with the affine map that carries its ``k`` neighbours from the first
frame to this one, evaluated at the track. Its neighbours are the tracks seen in both frames
that are nearest to it in both together (distance in the 4-vector of the two positions), so
that a patch does not straddle the boundary of a part that moves otherwise (an occluding
object, the other side of a fold): tracks that were close in the first frame and have moved
apart are not neighbours. The map is fitted by iteratively reweighted least squares with
Cauchy weights (scale 2.385 x the neighbours' median misfit, the constant that gives 95 %
efficiency under Gaussian noise), so that a neighbour that drifts too has little say.
A position farther from the prediction than the forward-backward check lets a round trip
miss (``sqrt(_FB_CONSTANT)`` px, the tracker's own tolerance for a position it can trust)
is marked lost in that frame only; the track keeps the frames where it agrees.

Cost: per frame a k-d tree over the P seen points (in 4 dimensions) and P small (3 x 3)
systems per reweighting round, ``O(F P (log P + k))`` time and ``O(P k)`` memory.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["N_NEIGHBOURS", "neighbour_residuals", "departures"]

#: Neighbours whose affine motion predicts a track position (about three grid steps around
#: it at the default step).
N_NEIGHBOURS = 24
#: Reweighting rounds of the affine fit after the plain least-squares one.
_REWEIGHTS = 3
#: Cauchy scale over the median absolute residual (95 % efficiency at Gaussian noise).
_CAUCHY = 2.385
#: Floor of the residual scale (px), for neighbours that fit the map exactly.
_MIN_SCALE_PX = 1e-3
#: Fewest neighbours that determine an affine map of the plane with one to spare.
_MIN_NEIGHBOURS = 4


def neighbour_residuals(W: np.ndarray, visibility: np.ndarray, k: int = N_NEIGHBOURS) -> np.ndarray:
    """Distance (px) of every track position from its neighbours' affine motion.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Pixel positions, rows ``2f``, ``2f + 1`` = x, y of frame ``f``; every track is seen in
        frame 0 (the tracker's grid), NaN where lost.
    visibility : ndarray of shape (F, P), bool
    k : int
        Neighbours per track.

    Returns
    -------
    residual : ndarray of shape (F, P)
        ``|x_fp - A_f(x_0p)|`` in pixels, with ``A_f`` the robust affine fit of the ``k``
        tracks seen in frame ``f`` nearest to ``p`` in frames 0 and ``f`` together; 0 in
        frame 0, NaN where the track is not seen or fewer than :data:`_MIN_NEIGHBOURS`
        neighbours are.
    """
    n_frames, n_points = visibility.shape
    positions = W.reshape(n_frames, 2, n_points).transpose(0, 2, 1)
    residual = np.where(visibility, 0.0, np.nan)
    for f in range(1, n_frames):
        seen = np.flatnonzero(visibility[0] & visibility[f])
        n_neighbours = min(k, seen.size - 1)
        if n_neighbours < _MIN_NEIGHBOURS:
            residual[f, seen] = np.nan
            continue
        both = np.concatenate([positions[0, seen], positions[f, seen]], axis=1)  # (n, 4)
        _, nearest = cKDTree(both).query(both, n_neighbours + 1)
        neighbours = seen[nearest[:, 1:]]  # (n, k): the first is the point itself
        source = positions[0, neighbours] - positions[0, seen][:, None]  # centred on the point
        predicted = _robust_affine_at_origin(source, positions[f, neighbours])
        residual[f, seen] = np.linalg.norm(positions[f, seen] - predicted, axis=1)
    return residual


def _robust_affine_at_origin(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(n, 2): the affine maps fitted from ``source`` (n, k, 2) to ``target`` (n, k, 2) by
    Cauchy-weighted least squares, each evaluated at the origin (its translation)."""
    design = np.concatenate([source, np.ones(source.shape[:2] + (1,))], axis=2)  # (n, k, 3)
    weights = np.ones(source.shape[:2])
    for _ in range(_REWEIGHTS):
        misfit = np.linalg.norm(target - design @ _weighted_fit(design, target, weights), axis=2)
        scale = _CAUCHY * np.maximum(np.median(misfit, axis=1, keepdims=True), _MIN_SCALE_PX)
        weights = 1.0 / (1.0 + (misfit / scale) ** 2)  # (n, k)
    return _weighted_fit(design, target, weights)[:, 2]


def _weighted_fit(design: np.ndarray, target: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n, 3, 2): weighted least-squares coefficients of ``target`` (n, k, 2) on ``design``
    (n, k, 3) with ``weights`` (n, k)."""
    normal = np.einsum("nk,nki,nkj->nij", weights, design, design) + 1e-9 * np.eye(3)
    return np.linalg.solve(normal, np.einsum("nk,nki,nkj->nij", weights, design, target))


def departures(W: np.ndarray, visibility: np.ndarray, tolerance_px: float) -> np.ndarray:
    """(F, P) bool: the seen positions farther than ``tolerance_px`` from their neighbours'
    affine motion (:func:`neighbour_residuals`)."""
    residual = neighbour_residuals(W, visibility)
    return np.nan_to_num(residual, nan=0.0) > tolerance_px
