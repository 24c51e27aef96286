"""Camera rotations from the calibration of dominant planes, robustly averaged over groups.

A sheet (a flag, a cloth, a bumpy surface) is far wider than it is deep, and its depth is
what deforms: the third singular direction of its tracks is mostly deformation, so a rigid
(rank-3) factorisation puts the deformation into the rotations (the windowed and rigid
estimates were 20-37 degrees off on the synthetic flags). Its first two directions are the
sheet's in-plane extent seen foreshortened, which the deformation barely changes. This module
recovers the rotations from them alone.

Plane calibration (one group of tracks, :func:`plane_candidates`): ``W_g ~ M B`` at rank 2
(``M = U_2 S_2^{1/2}``, 2F x 2). In a frame attached to the plane, frame f sees it through the
first two columns of its rotation, ``A_f = M_f H`` (2 x 2) for one unknown 2 x 2 H; the
rows of ``R_f = [A_f | c_f]`` are orthonormal when ``I - A_f A_f^T = c_f c_f^T`` is of rank
one, i.e. ``det(I - M_f P M_f^T) = 0`` with ``P = H H^T``:

    tr(M_f P M_f^T) - det(M_f)^2 det(P) = 1,

one equation per frame, linear in ``(P, det P)``: solved by linear least squares, then by
Gauss-Newton with ``det P`` tied to P. ``c_f`` follows up to its sign: the plane seen from
the front or from behind (``R_f`` or ``R_f D``, ``D = diag(1, 1, -1)``), the depth reversal of
orthographic views of a plane, separately in every frame. The signs of the whole object are
chosen as the path of smallest total change between consecutive frames (:func:`sign_path`,
exact dynamic programming over the two states per frame).

Groups (``n_groups > 1``): every k-means group of tracks (:func:`group_labels`) gives its own
plane and candidates, related to the camera by one orthogonal ``Q_g`` of its own. The
rotations minimise ``sum_g sqrt(rms_g^2 + delta_g^2)`` (rms_g: RMS chordal misfit of group
g's nearest candidates, ``E_gf Q_g^T``, to ``R_f``), an L1 (geometric-median) cost over
groups, by iteratively reweighted least squares (Weiszfeld; Hartley et al., "Rotation
averaging", IJCV 2013) from the whole object's rotations (:func:`robust_average`).
``delta_g`` is the Davis-Kahan bound on the tilt of the group's plane: its strongest
unmodelled singular value (the 3rd, or at least what white noise of the tracks' estimated
variance puts there) over the gap to the 2nd; this is how the noise enters, with no threshold.
``n_groups = 1`` is the whole object alone (the ablation).

Costs (F frames, P points, G groups): one 2F x 2F Gram matrix per group, O(F^2 P) in all
(O(F P^2 / G) for long sequences of few tracks, through the smaller side); the calibration
O(F) per Gauss-Newton step; the sign path O(F); each IRLS iteration O(G F). Nothing grows
with P^2 (beyond one group's size) or with F^2 beyond the Gram matrices.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from sklearn.cluster import KMeans

from moju_core.cameras.refinement import project_to_stiefel

__all__ = [
    "IRLS_ITERATIONS",
    "MIN_GROUP_SIZE",
    "group_labels",
    "plane_candidates",
    "plane_rotations",
    "robust_average",
    "sign_path",
]

#: Fewest tracks a group needs: a plane needs 3, the spare ones give its noise some room.
MIN_GROUP_SIZE = 8

#: Most IRLS iterations of :func:`robust_average` (it stops earlier when the rotations stop
#: changing, to 1e-10).
IRLS_ITERATIONS = 50


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


def _top_factor(tracks: np.ndarray) -> np.ndarray:
    """Left singular vectors and singular values of a (2F, n) matrix, through its smaller
    Gram matrix; returns ``(left[:, :2] * sqrt(s[:2]), s)``."""
    n_rows, n_cols = tracks.shape
    if n_rows <= n_cols:
        eigenvalues, vectors = np.linalg.eigh(tracks @ tracks.T)
        eigenvalues, vectors = eigenvalues[::-1], vectors[:, ::-1]
        singular = np.sqrt(np.clip(eigenvalues, 0.0, None))
        left = vectors[:, :2]
    else:
        eigenvalues, vectors = np.linalg.eigh(tracks.T @ tracks)
        eigenvalues, vectors = eigenvalues[::-1], vectors[:, ::-1]
        singular = np.sqrt(np.clip(eigenvalues, 0.0, None))
        left = tracks @ vectors[:, :2] / np.maximum(singular[:2], 1e-300)
    return left * np.sqrt(singular[:2]), singular


def plane_candidates(tracks: np.ndarray, noise_variance: float = 0.0) -> tuple[np.ndarray, float]:
    """Both rotations of every frame that the calibration of one plane allows.

    Parameters
    ----------
    tracks : ndarray of shape (2F, n)
        Tracks of one group (or the whole object), F >= 4, n >= 3; centred here.
    noise_variance : float, default 0
        Estimated variance of the noise of every entry (squared units of the tracks).

    Returns
    -------
    candidates : ndarray of shape (F, 2, 2, 3)
        ``candidates[f, 0]`` and ``candidates[f, 1] = candidates[f, 0] D``: frame f seen
        from either side of the plane, rows orthonormal, in a frame attached to the plane.
    delta : float
        Davis-Kahan bound on the tilt of the fitted plane (radians, dimensionless): the
        strongest unmodelled singular value over its gap to the second one (1e6 for a
        degenerate group).
    """
    n_frames, size = tracks.shape[0] // 2, tracks.shape[1]
    tracks = tracks - tracks.reshape(n_frames, 2, size).mean(axis=2).reshape(-1, 1)
    factor, singular = _top_factor(tracks)
    M = factor.reshape(n_frames, 2, 2)
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
    candidates = project_to_stiefel(np.stack([front, back], axis=1))
    # Largest singular value of white noise in a (2F x n) block: sigma (sqrt(2F) + sqrt(n)).
    noise = np.sqrt(max(noise_variance, 0.0)) * (np.sqrt(2 * n_frames) + np.sqrt(size))
    third = singular[2] if singular.size > 2 else 0.0
    unmodelled = float(np.hypot(third, noise))
    gap = singular[1] - unmodelled
    delta = unmodelled / gap if gap > 1e-12 * singular[0] else 1e6
    return candidates, float(min(delta, 1e6))


def sign_path(candidates: np.ndarray) -> np.ndarray:
    """The candidate of every frame on the path of least change between frames.

    Minimises ``sum_f ||R_{f+1} - R_f||_F^2`` over the two candidates per frame by dynamic
    programming (Viterbi), O(F).

    Parameters
    ----------
    candidates : ndarray of shape (F, 2, 2, 3)

    Returns
    -------
    ndarray of shape (F, 2, 3)
    """
    n_frames = candidates.shape[0]
    cost = np.zeros(2)
    back = np.zeros((n_frames, 2), dtype=np.int64)
    for f in range(1, n_frames):
        step = np.sum((candidates[f][:, None] - candidates[f - 1][None]) ** 2, axis=(2, 3))
        total = step + cost[None]
        back[f] = np.argmin(total, axis=1)
        cost = total.min(axis=1)
    choice = np.zeros(n_frames, dtype=np.int64)
    choice[-1] = int(np.argmin(cost))
    for f in range(n_frames - 1, 0, -1):
        choice[f - 1] = back[f, choice[f]]
    return candidates[np.arange(n_frames), choice]


def _align(candidates: np.ndarray, rotations: np.ndarray, rounds: int = 3) -> tuple:
    """Each group's orthogonal Q_g and nearest candidates against given rotations.

    Parameters
    ----------
    candidates : ndarray of shape (G, F, 2, 2, 3)
    rotations : ndarray of shape (F, 2, 3)

    Returns
    -------
    aligned : ndarray of shape (G, F, 2, 3)
        The nearest candidate of every frame, ``E_gf Q_g^T``.
    rms : ndarray of shape (G,)
        RMS over frames of ``||E_gf Q_g^T - R_f||_F``.
    """
    # Start from the in-plane part (the mean of the two candidates has no depth column).
    Q = project_to_stiefel(np.einsum("fia,gfib->gab", rotations, candidates.mean(axis=2)))
    for _ in range(rounds):
        turned = np.einsum("gfcib,gab->gfcia", candidates, Q)
        distance = np.sum((turned - rotations[None, :, None]) ** 2, axis=(3, 4))
        nearest = np.argmin(distance, axis=2)
        picked = np.take_along_axis(candidates, nearest[:, :, None, None, None], axis=2)[:, :, 0]
        # Q_g = argmin sum_f ||E_gf - R_f Q|| over O(3): polar factor of sum_f R_f^T E_gf.
        Q = project_to_stiefel(np.einsum("fia,gfib->gab", rotations, picked))
    aligned = np.einsum("gfib,gab->gfia", picked, Q)
    rms = np.sqrt(np.mean(np.sum((aligned - rotations[None]) ** 2, axis=(2, 3)), axis=1))
    return aligned, rms


def robust_average(
    candidates: np.ndarray,
    delta: np.ndarray,
    start: np.ndarray,
    *,
    iterations: int = IRLS_ITERATIONS,
) -> tuple[np.ndarray, np.ndarray]:
    """Rotations minimising ``sum_g sqrt(rms_g^2 + delta_g^2)``, by IRLS from a start.

    Parameters
    ----------
    candidates : ndarray of shape (G, F, 2, 2, 3)
        Every group's two candidates per frame (:func:`plane_candidates`).
    delta : ndarray of shape (G,)
        Every group's expected error (:func:`plane_candidates`).
    start : ndarray of shape (F, 2, 3)
    iterations : int

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    weights : ndarray of shape (G,)
        The final weights ``1 / sqrt(rms_g^2 + delta_g^2)``.
    """
    rotations = start
    weights = np.ones(candidates.shape[0])
    for _ in range(iterations):
        aligned, rms = _align(candidates, rotations)
        weights = 1.0 / np.sqrt(rms**2 + delta**2 + 1e-30)
        updated = project_to_stiefel(np.einsum("g,gfia->fia", weights, aligned))
        change = float(np.max(np.abs(updated - rotations)))
        rotations = updated
        if change < 1e-10:
            break
    return rotations, weights


def plane_rotations(
    W: np.ndarray,
    *,
    n_groups: int = 1,
    noise_variance: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """Camera rotations of a sheet-like object from its dominant plane(s).

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Centred tracks, F >= 4, P >= 3.
    n_groups : int, default 1
        Groups of tracks whose planes are averaged; 1: the whole object's plane alone.
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
    whole, _ = plane_candidates(W, noise_variance)
    rotations = sign_path(whole)
    labels = group_labels(W, n_groups, seed)
    n_found = int(labels.max()) + 1
    if n_found == 1:
        return rotations
    per_group = [plane_candidates(W[:, labels == g], noise_variance) for g in range(n_found)]
    candidates = np.stack([c for c, _ in per_group])
    delta = np.array([d for _, d in per_group])
    rotations, _ = robust_average(candidates, delta, rotations)
    return rotations
