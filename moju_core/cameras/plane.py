"""Camera rotations from the calibration of a sheet's dominant plane, fitted robustly to groups.

A sheet (a flag, a cloth, a bumpy surface) is far wider than it is deep, and its depth is
what deforms: the third singular direction of its tracks is mostly deformation, so a rigid
(rank-3) factorisation puts the deformation into the rotations (the windowed and rigid
estimates were 20-37 degrees off on the synthetic flags). Its first two directions are the
sheet's in-plane extent seen foreshortened, which the deformation barely changes. This module
recovers the rotations from them alone.

Plane calibration (:func:`calibrate_plane`): ``W_g ~ M B`` at rank 2
(``M = U_2 S_2^{1/2}``, 2F x 2). In a frame attached to the plane, frame f sees it through the
first two columns of its rotation, ``A_f = M_f H`` (2 x 2) for one unknown 2 x 2 H; the
rows of ``R_f = [A_f | c_f]`` are orthonormal when ``I - A_f A_f^T = c_f c_f^T`` is of rank
one, i.e. ``det(I - M_f P M_f^T) = 0`` with ``P = H H^T``:

    tr(M_f P M_f^T) - det(M_f)^2 det(P) = 1,

one equation per frame, linear in ``(P, det P)``: solved by linear least squares, then by
Gauss-Newton with ``det P`` tied to P. ``c_f`` follows up to its sign: the plane seen from
the front or from behind (``R_f`` or ``R_f D``, ``D = diag(1, 1, -1)``), the depth reversal of
orthographic views of a plane, separately in every frame. The signs of the whole object are
chosen as the path of smallest total acceleration, ``sum_f ||R_{f+1} - 2 R_f + R_{f-1}||^2``
(:func:`sign_path`, exact dynamic programming over the pairs of states of consecutive frames).
Smallest total change instead (first differences) prefers a camera that bounces off the
plane's normal to one that crosses it, and chose wrong segments on the design seeds
(flag-osc seed 1: 21 degrees off against 6 with acceleration).

Groups (``n_groups > 1``): the plane is fitted to the tracks with one weight per k-means
group (:func:`group_labels`), found by iteratively reweighted least squares as the L1 (Weiszfeld)
fit ``min sum_g n_g sqrt(r_g^2 + sigma^2)``, r_g the RMS distance of group g's tracks from the
rank-2 subspace and sigma^2 the tracks' estimated noise variance: groups that leave the plane
(deform out of it) are outvoted, and the noise, not a threshold, bounds how much a group that
stays in it can weigh (:func:`group_weights`). ``n_groups = 1`` is the plain rank-2 fit (the
ablation).

Costs (F frames, P points, G groups): each IRLS iteration one weighted Gram matrix, O(F^2 P)
(through the P x P one, O(F P^2), for long sequences of few tracks) and O(F P) residuals; the
k-means O(F P G) per Lloyd iteration on at most 50 G sampled tracks; the calibration O(F) per
Gauss-Newton step; the sign path O(F). Nothing grows with P^2 for dense tracks.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from sklearn.cluster import KMeans

from moju_core.cameras.refinement import project_to_stiefel

__all__ = [
    "IRLS_ITERATIONS",
    "DEFAULT_GROUPS",
    "MIN_GROUP_SIZE",
    "calibrate_plane",
    "group_labels",
    "group_weights",
    "plane_rotations",
    "sign_path",
]

#: Fewest tracks a group needs: a plane needs 3, the spare ones give its noise some room
#: (24 tracks of a turning flag: 3 groups 1.9 degrees off, 4 groups of 6 tracks 2.5; measured
#: in docs/constants.md, where 12 tracks show the other side).
MIN_GROUP_SIZE = 8

#: Groups of :func:`plane_rotations` when not given: several, so that the L1 fit can outvote
#: the parts of a sheet that leave its plane, each of many tracks (the measurements are in
#: docs/constants.md and docs/cameras.md).
DEFAULT_GROUPS = 4

#: Most IRLS iterations of :func:`group_weights` (it stops when the relative weights change by
#: less than 1e-6).
IRLS_ITERATIONS = 30


def group_labels(W: np.ndarray, n_groups: int, seed: int = 0) -> np.ndarray:
    """k-means groups of the tracks by their whole trajectories (the columns of W).

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Centred tracks.
    n_groups : int
        Requested groups; fewer when groups would hold fewer than ``MIN_GROUP_SIZE`` tracks.
    seed : int

    Returns
    -------
    ndarray of shape (P,), int64
        Labels ``0 .. G - 1``.
    """
    n_points = W.shape[1]
    n_groups = max(1, min(int(n_groups), n_points // MIN_GROUP_SIZE))
    if n_groups == 1:
        return np.zeros(n_points, dtype=np.int64)
    features = W.T
    kmeans = KMeans(n_clusters=n_groups, init="k-means++", n_init=1, random_state=seed)
    sample_size = 50 * n_groups
    if n_points > sample_size:
        sample = np.random.default_rng(seed).choice(n_points, sample_size, replace=False)
        labels = kmeans.fit(features[sample]).predict(features)
    else:
        labels = kmeans.fit_predict(features)
    _, labels = np.unique(labels, return_inverse=True)
    return labels.astype(np.int64)


def _plane_factor(W: np.ndarray, point_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rank-2 left factor of the weighted, re-centred tracks.

    Returns
    -------
    basis : ndarray of shape (2F, 2)
        Orthonormal top-2 left singular vectors of ``(W - c) diag(sqrt(w))``, c the weighted
        centroid of every row.
    singular : ndarray of shape (2,)
        Their singular values.
    """
    root = np.sqrt(point_weights)
    centroid = (W @ point_weights) / point_weights.sum()
    weighted = (W - centroid[:, None]) * root
    if weighted.shape[0] <= weighted.shape[1]:
        values, vectors = np.linalg.eigh(weighted @ weighted.T)
        basis = vectors[:, -2:][:, ::-1]
        singular = np.sqrt(np.clip(values[-2:][::-1], 0.0, None))
    else:
        values, vectors = np.linalg.eigh(weighted.T @ weighted)
        singular = np.sqrt(np.clip(values[-2:][::-1], 0.0, None))
        basis = weighted @ vectors[:, -2:][:, ::-1] / np.maximum(singular, 1e-300)
    return basis, singular


def group_weights(
    W: np.ndarray, labels: np.ndarray, noise_variance: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The L1 fit of one plane to groups of tracks, by IRLS (see the module docstring).

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Tracks (centred here, with the weights).
    labels : ndarray of shape (P,), int
        Group of every track, ``0 .. G - 1``.
    noise_variance : float, default 0
        Estimated variance of the noise of every entry of W.

    Returns
    -------
    weights : ndarray of shape (G,)
        ``1 / sqrt(r_g^2 + sigma^2)`` at the fit, scaled to a largest weight of 1.
    basis : ndarray of shape (2F, 2)
        The fitted plane's left singular vectors.
    singular : ndarray of shape (2,)
    """
    n_groups = int(labels.max()) + 1
    counts = np.bincount(labels, minlength=n_groups).astype(np.float64)
    weights = np.ones(n_groups)
    floor = max(float(noise_variance), 0.0) + 1e-30
    for _ in range(IRLS_ITERATIONS if n_groups > 1 else 1):
        point_weights = weights[labels]
        basis, singular = _plane_factor(W, point_weights)
        centred = W - ((W @ point_weights) / point_weights.sum())[:, None]
        residual = centred - basis @ (basis.T @ centred)
        energy = np.einsum("ip,ip->p", residual, residual)
        mean_square = np.bincount(labels, weights=energy, minlength=n_groups) / (
            counts * W.shape[0]
        )
        updated = 1.0 / np.sqrt(mean_square + floor)
        updated /= updated.max()
        change = float(np.max(np.abs(updated - weights)))
        weights = updated
        if change < 1e-6:
            break
    return weights, basis, singular


def calibrate_plane(basis: np.ndarray, singular: np.ndarray) -> np.ndarray:
    """Both rotations of every frame that the calibration of a plane allows.

    Parameters
    ----------
    basis : ndarray of shape (2F, 2)
        Top-2 left singular vectors of the (weighted) tracks, F >= 4.
    singular : ndarray of shape (2,)
        Their singular values.

    Returns
    -------
    ndarray of shape (F, 2, 2, 3)
        ``[f, 0]`` and ``[f, 1] = [f, 0] D``: frame f seen from either side of the plane, rows
        orthonormal, in a frame attached to the plane.
    """
    n_frames = basis.shape[0] // 2
    M = (basis * np.sqrt(singular)).reshape(n_frames, 2, 2)
    # tr(M P M^T) = p11 |m_1|^2 + 2 p12 m_1.m_2 + p22 |m_2|^2 over M's columns m_1, m_2.
    linear = np.stack(
        [
            np.einsum("fi,fi->f", M[:, :, 0], M[:, :, 0]),
            2.0 * np.einsum("fi,fi->f", M[:, :, 0], M[:, :, 1]),
            np.einsum("fi,fi->f", M[:, :, 1], M[:, :, 1]),
        ],
        axis=1,
    )
    det_m2 = np.linalg.det(M) ** 2
    system = np.column_stack([linear, -det_m2])
    solution, *_ = np.linalg.lstsq(system, np.ones(n_frames), rcond=None)

    def residuals(p: np.ndarray) -> np.ndarray:
        return linear @ p - det_m2 * (p[0] * p[2] - p[1] ** 2) - 1.0

    p = least_squares(residuals, solution[:3], method="lm").x
    P = np.array([[p[0], p[1]], [p[1], p[2]]])
    eigenvalues, vectors = np.linalg.eigh(P)
    H = vectors * np.sqrt(np.clip(eigenvalues, 0.0, None))
    A = M @ H  # (F, 2, 2)
    remainder = np.eye(2) - A @ np.swapaxes(A, 1, 2)
    values, directions = np.linalg.eigh(remainder)
    c = directions[:, :, 1] * np.sqrt(np.clip(values[:, 1], 0.0, None))[:, None]
    front = np.concatenate([A, c[:, :, None]], axis=2)
    back = np.concatenate([A, -c[:, :, None]], axis=2)
    return project_to_stiefel(np.stack([front, back], axis=1))


def sign_path(candidates: np.ndarray) -> np.ndarray:
    """The candidate of every frame on the path of least acceleration.

    Minimises ``sum_f ||R_{f+1} - 2 R_f + R_{f-1}||_F^2`` over the two candidates per frame
    by dynamic programming over the states ``(s_{f-1}, s_f)`` (4 per frame), O(F).

    Parameters
    ----------
    candidates : ndarray of shape (F, 2, 2, 3)

    Returns
    -------
    ndarray of shape (F, 2, 3)
    """
    n_frames = candidates.shape[0]
    if n_frames < 3:
        return candidates[:, 0]
    # State index 2 a + b for (s_{f-1}, s_f) = (a, b).
    a, b, c = np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")
    a, b, c = a.ravel(), b.ravel(), c.ravel()
    cost = np.zeros(4)
    back = np.zeros((n_frames, 4), dtype=np.int64)
    for f in range(2, n_frames):
        step = candidates[f, c] - 2.0 * candidates[f - 1, b] + candidates[f - 2, a]
        total = cost[2 * a + b] + np.sum(step**2, axis=(1, 2))  # (8,) transitions
        # Transitions t = 4 a + (2 b + c): the best predecessor a of every state (b, c).
        by_predecessor = total.reshape(2, 4)
        best = np.argmin(by_predecessor, axis=0)
        new_cost = by_predecessor[best, np.arange(4)]
        back[f] = 2 * best + np.arange(4) // 2
        cost = new_cost
    state = int(np.argmin(cost))
    choice = np.zeros(n_frames, dtype=np.int64)
    choice[-1], choice[-2] = state % 2, state // 2
    for f in range(n_frames - 1, 1, -1):
        state = int(back[f, state])
        choice[f - 2] = state // 2
    return candidates[np.arange(n_frames), choice]


def plane_rotations(
    W: np.ndarray,
    *,
    n_groups: int = DEFAULT_GROUPS,
    noise_variance: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """Camera rotations of a sheet-like object from its dominant plane.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Tracks (translations are removed here), F >= 4, P >= 3.
    n_groups : int, default DEFAULT_GROUPS
        Groups of tracks weighted by the L1 fit; 1: the plain rank-2 fit (the ablation).
    noise_variance : float, default 0
        Estimated variance of the noise of every entry of W
        (:func:`moju_core.spectrum.noise_variance`).
    seed : int, default 0
        Seed of the k-means groups.

    Returns
    -------
    ndarray of shape (F, 2, 3)
        Rotations with orthonormal rows, up to one global orthogonal transform.
    """
    W = np.asarray(W, dtype=np.float64)
    labels = group_labels(W, n_groups, seed)
    _, basis, singular = group_weights(W, labels, noise_variance)
    return sign_path(calibrate_plane(basis, singular))
