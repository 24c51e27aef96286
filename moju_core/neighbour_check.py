"""Track positions that leave their neighbours' motion, treated as missing by the solve.

Chained optical flow drifts where a surface turns away from the camera or meets its
silhouette: there the flow is smoothed with what lies beside the object, the forward and
backward flows agree on the wrong motion, and a track slides by a fraction of a pixel per
frame until a consistency check finally stops it, several pixels off. On rendered footage
1-4 % of the tracks err by more than 2 px in some frame, most of them tracks that are lost a
few frames later, and those few positions cost the perspective solve more depth accuracy
than the rest of the tracking error together: each is a viewing ray in the wrong place.

Over a small patch the image motion of a smooth surface is close to affine, so each track
position is compared with the affine map that carries the track's ``k`` neighbours from its
reference frame (the first that sees it) to this one, evaluated at the track. Its neighbours
are the tracks seen in both frames that are nearest to it in both together (distance in the
4-vector of the two positions), so that a patch does not straddle the boundary of a part
that moves otherwise (an occluding object, the other side of a fold): tracks that were close
and have moved apart are not neighbours. The map is fitted by least squares reweighted
:data:`_REWEIGHTS` times with Cauchy weights (scale 2.385 x the neighbours' median misfit,
the constant that gives 95 % efficiency under Gaussian noise), so that neighbours that drift
too have little say. A position is a departure when it is farther from the prediction than
the neighbours' own median distance from it plus :data:`TOLERANCE_PX`: at a fold, where the
motion is not affine, the neighbours are off the map too, and only what stands out from them
counts. Departures are sought only where the neighbours' motion explains the tracks at all
(:func:`explained`: dense tracks of a video, not sparse points seen from views far apart).

Cost: per frame and reference frame a k-d tree over the P seen points (in 4 dimensions) and
P small (3 x 3) systems per reweighting round, ``O(F P (log P + k))`` time and ``O(P k)``
memory; about 0.1 s per frame for 10,000 tracks, small against the perspective solve.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from moju_core.validation import MIN_FRAMES_PER_POINT, MIN_POINTS_PER_FRAME

__all__ = [
    "N_NEIGHBOURS",
    "TOLERANCE_PX",
    "departures",
    "explained",
    "neighbour_residuals",
    "trusted",
]

#: Neighbours whose affine motion predicts a track position (about three grid steps around
#: it on the tracker's grid).
N_NEIGHBOURS = 24
#: A position farther than this (px) from its neighbours' affine motion, beyond their own
#: median distance from it, is a departure: the round-trip error the tracker's
#: forward-backward check tolerates, sqrt(0.8 px^2) (``moju_core.footage.tracking``).
TOLERANCE_PX = float(np.sqrt(0.8))
#: Reweighting rounds of the affine fit after the plain least-squares one.
_REWEIGHTS = 3
#: Cauchy scale over the median absolute residual (95 % efficiency at Gaussian noise).
_CAUCHY = 2.385
#: Floor of the residual scale (px), for neighbours that fit the map exactly.
_MIN_SCALE_PX = 1e-3
#: Fewest neighbours that determine an affine map of the plane with one to spare.
_MIN_NEIGHBOURS = 4


def neighbour_residuals(
    W: np.ndarray, visibility: np.ndarray, k: int = N_NEIGHBOURS
) -> tuple[np.ndarray, np.ndarray]:
    """Distance (px) of every track position from its neighbours' affine motion, and theirs.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Pixel positions, rows ``2f``, ``2f + 1`` = x, y of frame ``f``; NaN where not seen.
    visibility : ndarray of shape (F, P), bool
    k : int
        Neighbours per track.

    Returns
    -------
    residual : ndarray of shape (F, P)
        ``|x_fp - A_f(x_sp)|`` in pixels, with ``s`` the first frame that sees ``p`` and
        ``A_f`` the robust affine fit of the ``k`` tracks seen in frames ``s`` and ``f``
        nearest to ``p`` in both together; 0 in frame ``s``, NaN where the track is not seen
        or fewer than :data:`_MIN_NEIGHBOURS` neighbours are.
    typical : ndarray of shape (F, P)
        The median distance of the ``k`` neighbours themselves from ``A_f`` (px): how far
        the motion there is from affine (large at a fold, an edge, or where neighbours drift
        apart); 0 and NaN as ``residual``.
    """
    n_frames, n_points = visibility.shape
    positions = W.reshape(n_frames, 2, n_points).transpose(0, 2, 1)
    residual = np.full((n_frames, n_points), np.nan)
    typical = residual.copy()
    first = np.argmax(visibility, axis=0)
    for s in np.unique(first[visibility.any(axis=0)]):
        group = np.flatnonzero((first == s) & visibility[s])
        residual[s, group] = typical[s, group] = 0.0
        for f in range(s + 1, n_frames):
            judged = group[visibility[f, group]]
            pool = visibility[s] & visibility[f]
            residual[f, judged], typical[f, judged] = _residuals(
                positions[s], positions[f], judged, k, pool
            )
    return residual, typical


def _residuals(
    start: np.ndarray, now: np.ndarray, judged: np.ndarray, k: int, both: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(n,) residuals of the tracks ``judged`` (n,) from frame positions ``start`` (P, 2) to
    ``now`` (P, 2), neighbours among the tracks ``both`` (P,) bool seen in the two frames,
    and (n,) their neighbours' median residuals."""
    pool = np.flatnonzero(both)
    n_neighbours = min(k, pool.size - 1)
    if judged.size == 0 or n_neighbours < _MIN_NEIGHBOURS:
        return np.full(judged.size, np.nan), np.full(judged.size, np.nan)
    places = np.concatenate([start[pool], now[pool]], axis=1)  # (m, 4)
    query = np.concatenate([start[judged], now[judged]], axis=1)
    _, nearest = cKDTree(places).query(query, n_neighbours + 1)
    neighbours = pool[nearest[:, 1:]]  # (n, k): the first is the point itself
    source = start[neighbours] - start[judged][:, None]  # centred on the point
    coefficients = _robust_affine(source, now[neighbours])
    misfit = np.linalg.norm(now[neighbours] - _apply(source, coefficients), axis=2)
    residual = np.linalg.norm(now[judged] - coefficients[:, 2], axis=1)  # the map at the point
    return residual, np.median(misfit, axis=1)


def _robust_affine(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(n, 3, 2): the affine maps from ``source`` (n, k, 2) to ``target`` (n, k, 2), fitted by
    Cauchy-weighted least squares: rows 0-1 the linear part, row 2 the translation (the map
    at the origin)."""
    weights = np.ones(source.shape[:2])
    for _ in range(_REWEIGHTS):
        fitted = _apply(source, _weighted_fit(source, target, weights))
        misfit = np.linalg.norm(target - fitted, axis=2)  # (n, k)
        scale = _CAUCHY * np.maximum(np.median(misfit, axis=1, keepdims=True), _MIN_SCALE_PX)
        weights = 1.0 / (1.0 + (misfit / scale) ** 2)
    return _weighted_fit(source, target, weights)


def _apply(source: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """(n, k, 2): the affine maps ``coefficients`` (n, 3, 2) at the points ``source``."""
    return source @ coefficients[:, :2] + coefficients[:, 2:3]


def _weighted_fit(source: np.ndarray, target: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n, 3, 2): weighted least-squares affine maps from ``source`` (n, k, 2) to ``target``
    (n, k, 2) with ``weights`` (n, k)."""
    design = np.concatenate([source, np.ones(source.shape[:2] + (1,))], axis=2)  # (n, k, 3)
    weighted = (design * weights[:, :, None]).transpose(0, 2, 1)  # (n, 3, k)
    return np.linalg.solve(weighted @ design + 1e-9 * np.eye(3), weighted @ target)


def departures(W: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """(F, P) bool: the seen positions farther from their neighbours' affine motion than
    :data:`TOLERANCE_PX` beyond the neighbours' own median distance from it
    (:func:`neighbour_residuals`), where that motion explains the tracks (:func:`explained`);
    none elsewhere."""
    residual, typical = (np.nan_to_num(a, nan=0.0) for a in neighbour_residuals(W, visibility))
    if not explained(residual):
        return np.zeros(visibility.shape, dtype=bool)
    return residual - typical > TOLERANCE_PX


def explained(residual: np.ndarray) -> bool:
    """Whether the neighbours' affine motion explains tracks with these ``residual`` (F, P)
    (px, 0 where not judged) to within :data:`TOLERANCE_PX`: the largest of N residuals drawn
    from the Rayleigh law of their median, ``sqrt(2 ln N) sigma``, is within it.

    Dense tracks of a video are (that bound is 0.16-0.66 px on rendered footage); sparse
    points seen from views far apart are not (3-150 px on the four real sequences of
    ``moju_core.datasets.totem``), and there a departure would say nothing about a track.
    """
    judged = residual[residual > 0]
    if judged.size < 2:
        return False
    sigma = np.median(judged) / np.sqrt(2 * np.log(2))
    return bool(np.sqrt(2 * np.log(judged.size)) * sigma <= TOLERANCE_PX)


def trusted(W: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """(F, P) bool: ``visibility`` without the :func:`departures`, except where that would
    leave a track seen in fewer than :data:`MIN_FRAMES_PER_POINT` frames (its positions are
    all kept) or then a frame with fewer than :data:`MIN_POINTS_PER_FRAME` points (its
    positions are all kept): the solver's minimums still hold."""
    hidden = departures(W, visibility)
    hidden[:, (visibility & ~hidden).sum(axis=0) < MIN_FRAMES_PER_POINT] = False
    hidden[(visibility & ~hidden).sum(axis=1) < MIN_POINTS_PER_FRAME] = False
    return visibility & ~hidden
