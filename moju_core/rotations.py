"""Camera rotations of an orthographic non-rigid sequence (the camera step of docs/solver.md).

Two estimators, selected by name in :func:`estimate_rotations`:

* ``"intersection"`` - Dai, Li and He, "A simple prior-free method for non-rigid
  structure-from-motion factorization" (CVPR 2012 / IJCV 2014), followed by a joint fit.
  The measurements are factorised at rank 3K, ``W ~ Pi_hat B_hat``; the unknown corrective
  column triple ``G_k`` (3K x 3) enters only through ``Q = G_k G_k^T``, on which every frame
  imposes two linear equations. ``Q`` is the positive semidefinite matrix of smallest trace
  in the (numerical) null space of those equations; its top three eigenpairs give ``G_k``
  and every frame block ``Pi_hat_f G_k = c_fk R_f`` gives a rotation (Dai et al.'s
  estimate). One triple fixes the rotations only to second order, so the rotations are
  then refined so that several triples of the motion factor are scaled copies of the same
  rotations (:func:`_fit_triples`). How many is decided by the data, not by K: the fit
  adds triples one at a time, in all directions of W that stand above the noise, as long
  as the new triple fits *exactly* - with no more misfit than the noise of W explains.
  Exactly low-rank sequences (K full xyz bases) have K such triples, and the fit is then
  the joint fit of all K; realistic deformations have fewer (the synthetic faces have 2,
  whatever K), and fitting the inexact ones as well pulled the rotations 4-23 degrees away
  from the truth (that was the previous version's failure on the project's sequences).
  The fit continues from Dai et al.'s estimate and moves away from it only for a clearly
  lower misfit, so that where the data leave the rotations undetermined (a few frames)
  the estimate stays near Dai et al.'s. A multi-start search guards against wrong minima
  under noise. A degenerate relaxation (Q of rank below 3) lowers K step by step, down to
  the rigid method; data in which not even one triple fits get a warning.
* ``"rigid"`` - Tomasi and Kanade's rank-3 factorisation with metric upgrade; exact for a
  rigid object and a fast fallback for nearly rigid ones.

Both work on the left singular vectors of W only, obtained from the 2F x 2F Gram matrix
``W W^T`` (or ``W^T W`` when there are fewer points than rows), so the cost in the number of
points P is a single matrix product. Rotations are defined up to one global rotation and a
reflection, which is inherent to orthographic structure from motion.
"""

from __future__ import annotations

import math
import warnings
from typing import Literal, NamedTuple

import numpy as np
import scipy.linalg
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from moju_core import feasibility
from moju_core.errors import MeasurementError
from moju_core.feasibility import min_frames_for_bases

__all__ = [
    "choose_n_bases",
    "estimate_rotations",
    "fit_rotations_to_shapes",
    "intersection_rotations",
    "min_frames_for_bases",
    "noise_variance",
    "project_to_stiefel",
    "rigid_from_factor",
    "rigid_rotations",
    "significant_rank",
    "spectrum",
]

RotationEstimator = Literal["intersection", "rigid"]

# Singular values of W below this fraction of the largest are treated as exact zeros. The
# Gram-matrix route computes s_i^2 with an absolute error of about eps * s_1^2, so singular
# values are only resolved down to about sqrt(eps) * s_1 ~ 1.5e-8 * s_1; 1e-6 stays clear of
# that floor while being far below any deformation that matters for the rotations.
_RANK_FLOOR = 1e-6
# Dai's trace relaxation only provides starting points (the joint fit then converges to
# rounding level), so a moderate ADMM tolerance is enough: 1e-4 .. 1e-8 gave the same final
# rotations on the project's sequences, and 1e-8 cost up to 1 s of iterations.
_ADMM_TOL = 1e-6
_ADMM_MAX_ITER = 2000
# Largest number of directions of W the joint fit works in (H is 3n x 3n).
_MAX_FIT_RANK = 30
# Longer sequences fit the corrective triples on this many frames spread evenly over the
# sequence (the triples do not depend on the frame), and every frame's rotation then follows
# from the fitted triples in closed form (_rotations_from_triples): the L-BFGS fit costs
# O(F) per iteration and needs more iterations for more frames.
_MAX_FIT_FRAMES = 100
# L-BFGS fit of the rotations to the motion factor (_refine_rotations): relative decrease of
# the misfit at which to stop, and iteration budget (tens to hundreds are used).
_REFINE_TOL = 1e-10
_REFINE_MAX_ITER = 1000
# Multi-start search: random 3-dim subspaces of the top _SUBSPACE_WIDTH eigenvectors of the
# relaxation's Q (besides its top-3 factor, the previous number of triples' fit and the
# rigid estimate), and the looser tolerance and budget of each search run.
_SUBSPACE_STARTS = 6
_SUBSPACE_WIDTH = 6
_SEARCH_TOL = 1e-6
_SEARCH_MAX_ITER = 300
# Q from the convex relaxation must have a clear third eigenvalue: lambda_3 >= this *
# lambda_1. Below it the top-3 factor is not a rotation basis and the estimate is rejected.
_DEGENERATE_EIGEN_RATIO = 1e-6
# A fitted triple is "exact" when its misfit (with the singular values as weights, so that
# white noise adds the same amount to every triple) is at most this many times the misfit
# that the noise of W alone gives a triple, 2 F sigma^2 (see _fit_triples). Measured after
# the fit (which lowers it): 0.55-1.1 for the triples of exactly low-rank sequences with
# 1-5.5 % noise; 1.4-3.4, and 0.97 in one case, for the second triple of the project's faces
# with 1 % noise, which the noise cuts off from the weak directions it needs and whose
# inclusion pulled the rotations 12-25 degrees. With 1.3 instead of 2 the faces kept
# 0.6-1.3 degrees in 3 of 4 seeds and the low-rank sequences lost nothing (they gained at
# 3-5.5 % noise, where a basis sinking into the noise was dropped); with 1.0 the same.
_EXACT_NOISE_RATIO = 1.3
# Without noise the noise floor is a rounding error and L-BFGS does not reach it: a triple is
# also exact when its eigenvalue of H is below this fraction of the largest one. At the true
# rotations of the project's noise-free faces the exact triples sit at 1e-16 and below, the
# inexact ones at 9e-6 and above (1e-7 .. 1e-6 for the single nearly exact triple of the
# 10-frame faces, where the noise test decides).
_EXACT_RELATIVE = 1e-8
# A fit whose k-th eigenvalue is this far below the (k + 1)-th fits k triples exactly. When
# the fit continued from the relaxation's estimate is exact like that, other starting points
# can only find other exact fits (several exist when the data do not determine the
# rotations, e.g. 10 frames), so the search keeps it and does not move away from it.
_LINEAGE_EXACT = 1e-4
# Otherwise another start replaces it only if its misfit is lower by more than 10 %.
_LINEAGE_MARGIN = 0.9


# ----------------------------------------------------------------------------------------
# Small geometric helpers
# ----------------------------------------------------------------------------------------


def project_to_stiefel(M: np.ndarray) -> np.ndarray:
    """Nearest matrices with orthonormal rows, for a stack of matrices.

    For ``M = U diag(s) V^T`` (thin SVD) the closest matrix with orthonormal rows in the
    Frobenius norm is ``U V^T`` (the orthogonal polar factor). A positive per-matrix scale
    is therefore divided out; a negative one is not (``-R`` has orthonormal rows too).

    Parameters
    ----------
    M : ndarray of shape (..., m, n) with m <= n
        Typically (F, 2, 3): scaled and noisy camera rotations.

    Returns
    -------
    ndarray of shape (..., m, n), float64
        Matrices whose rows are orthonormal (to about 1e-15).

    Raises
    ------
    ValueError
        If ``M`` has fewer than two dimensions or more rows than columns per matrix.
    """
    M = np.asarray(M, dtype=np.float64)
    if M.ndim < 2 or M.shape[-2] > M.shape[-1]:
        raise ValueError(
            f"project_to_stiefel needs matrices with at most as many rows as columns, "
            f"got an array of shape {M.shape}"
        )
    U, _, Vt = np.linalg.svd(M, full_matrices=False)
    return U @ Vt


def _svec_indices(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Upper-triangle indices of an n x n matrix and the svec weights (1 or sqrt(2))."""
    rows, cols = np.triu_indices(n)
    weights = np.where(rows == cols, 1.0, math.sqrt(2.0))
    return rows, cols, weights


def _svec(M: np.ndarray) -> np.ndarray:
    """Isometric vectorisation of symmetric matrices: (..., n, n) -> (..., n(n+1)/2).

    Off-diagonal entries are weighted by sqrt(2) so that ``svec(A) . svec(B) = <A, B>_F``;
    projections in svec coordinates are then Frobenius projections of matrices.
    """
    rows, cols, weights = _svec_indices(M.shape[-1])
    return M[..., rows, cols] * weights


def _smat(v: np.ndarray, n: int) -> np.ndarray:
    """Inverse of :func:`_svec` for one vector: (n(n+1)/2,) -> symmetric (n, n)."""
    rows, cols, weights = _svec_indices(n)
    M = np.zeros((n, n))
    M[rows, cols] = v / weights
    M[cols, rows] = v / weights
    return M


def _project_psd(M: np.ndarray) -> np.ndarray:
    """Frobenius projection of a symmetric matrix onto the PSD cone (eigenvalue clipping)."""
    eigenvalues, eigenvectors = np.linalg.eigh(M)
    return (eigenvectors * np.clip(eigenvalues, 0.0, None)) @ eigenvectors.T


# ----------------------------------------------------------------------------------------
# Validation and the spectrum of W
# ----------------------------------------------------------------------------------------


def _check_measurements(W: np.ndarray) -> np.ndarray:
    """Return W as a float64 array of shape (2F, P) or raise MeasurementError."""
    W = np.asarray(W, dtype=np.float64)
    if W.ndim != 2:
        raise MeasurementError(
            f"W must be a 2-D array of shape (2F, P), got an array of shape {W.shape}"
        )
    if W.shape[0] % 2 != 0:
        raise MeasurementError(
            f"W must have an even number of rows (x and y of every frame), got {W.shape[0]}"
        )
    if not np.all(np.isfinite(W)):
        raise MeasurementError("W contains NaN or infinite values; fill or drop those tracks")
    n_frames = W.shape[0] // 2
    feasibility.check_rotation_frames(n_frames)
    return W


def _check_n_bases(n_bases: int, n_frames: int, n_points: int) -> None:
    """Raise MeasurementError when W is too small for a rank-3K factorisation."""
    feasibility.check_n_bases(n_bases, n_frames, n_points)


class Spectrum(NamedTuple):
    """Left singular vectors and singular values of W, and its row Gram matrix if formed."""

    left: np.ndarray  # (2F, m), m = min(2F, P), decreasing singular values
    singular: np.ndarray  # (m,), decreasing, >= 0
    gram: np.ndarray | None  # (2F, 2F) W W^T when 2F <= P, else None


def spectrum(W: np.ndarray) -> Spectrum:
    """Left singular vectors and singular values of W through the smaller Gram matrix.

    With 2F <= P (dense tracking) the 2F x 2F matrix ``W W^T`` costs one product over the
    points, against a full SVD of the 2F x P matrix. Its eigenvalues carry an absolute error
    of about ``eps * s_1^2``, so singular values below ``~1e-8 s_1`` are not resolved; the
    rank rules in this module never rely on them (see ``_RANK_FLOOR``).

    Parameters
    ----------
    W : ndarray of shape (2F, P)

    Returns
    -------
    Spectrum
        Vectors of (numerically) zero singular values are arbitrary but orthonormal when
        2F <= P, and zero otherwise.
    """
    n_rows, n_points = W.shape
    if n_rows <= n_points:
        gram = W @ W.T
        eigenvalues, U = np.linalg.eigh(gram)
        eigenvalues, U = eigenvalues[::-1], U[:, ::-1]
        return Spectrum(U, np.sqrt(np.clip(eigenvalues, 0.0, None)), gram)
    eigenvalues, V = np.linalg.eigh(W.T @ W)
    eigenvalues, V = eigenvalues[::-1], V[:, ::-1]
    s = np.sqrt(np.clip(eigenvalues, 0.0, None))
    U = W @ V
    positive = s > 0
    U[:, positive] /= s[positive]
    U[:, ~positive] = 0.0
    return Spectrum(U, s, None)


def _gavish_donoho_threshold(s: np.ndarray, aspect: float) -> float:
    """Hard threshold on singular values for unknown white noise (Gavish and Donoho 2014).

    ``tau = omega(beta) * median(s)`` with their cubic approximation of ``omega`` for an
    m x n matrix, ``beta = m / n <= 1``. Singular values above ``tau`` are signal.
    """
    beta = min(aspect, 1.0 / aspect)
    omega = 0.56 * beta**3 - 0.95 * beta**2 + 1.82 * beta + 1.43
    return float(omega * np.median(s))


def significant_rank(s: np.ndarray, shape: tuple[int, int]) -> int:
    """Number of singular values of W above the noise (step 1 of :func:`choose_n_bases`).

    Parameters
    ----------
    s : ndarray
        Singular values of W, decreasing.
    shape : (int, int)
        Shape of W.

    Returns
    -------
    int
        How many exceed both the Gavish-Donoho threshold for unknown white noise and
        ``1e-6 s_1`` (below which the Gram route does not resolve them).
    """
    if s.size == 0 or s[0] <= 0.0:
        return 0
    threshold = max(_gavish_donoho_threshold(s, shape[0] / shape[1]), _RANK_FLOOR * s[0])
    return int(np.count_nonzero(s > threshold))


def _n_bases_from_spectrum(s: np.ndarray, shape: tuple[int, int], max_bases: int) -> int:
    """The rule of :func:`choose_n_bases` applied to given singular values (decreasing)."""
    n_rows, n_points = shape
    n_bases = math.ceil(significant_rank(s, shape) / 3)
    # Bounds: enough frames for the intersection constraints, enough points for the rank.
    by_frames = max(k for k in range(1, max_bases + 1) if min_frames_for_bases(k) <= n_rows // 2)
    by_points = (n_points - 1) // 3
    return max(1, min(n_bases, max_bases, by_frames, by_points))


def choose_n_bases(W: np.ndarray, max_bases: int = 10) -> int:
    """Number of shape bases K from the singular values of W.

    W = Pi B has rank at most 3K, so K is read off the numerical rank r of W:

    1. *Rank.* r counts the singular values above the Gavish-Donoho optimal hard threshold
       for white noise of unknown level, ``omega(beta) * median(s)`` (Gavish and Donoho,
       "The optimal hard threshold for singular values is 4/sqrt(3)", IEEE Trans. Inf.
       Theory 2014; ``beta`` is the aspect ratio of W), and above ``1e-6 s_1``, the
       resolution of the Gram-matrix route, which decides for noise-free data where the
       median is a rounding error. The median of the spectrum estimates the noise level
       because noise spreads over all ``min(2F, P)`` directions while the shape occupies
       only 3K of them; an energy fraction of the whole spectrum (e.g. 99.9 %) would
       instead grow with the noise and push K to its upper bound. Components below the
       noise are dropped: they cannot be estimated and would only make the intersection
       problem worse conditioned.
    2. *Bases.* ``K = ceil(r / 3)``: a basis whose three singular values are only partly
       above the noise is kept, since it still deforms the object.
    3. *Bounds.* ``1 <= K <= max_bases``, at most what the number of frames supports
       (:func:`min_frames_for_bases`), and ``3K <= P - 1`` (centred columns sum to zero).

    On noise-free data with K bases the rule returns K exactly; with Gaussian noise it
    returns K, or fewer when a weak basis sinks entirely below the noise (see the tests).

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Row-centred measurements (any scale).
    max_bases : int, default=10
        Upper bound on K.

    Returns
    -------
    int
        The number of shape bases K.

    Raises
    ------
    MeasurementError
        If W is not a finite (2F, P) array with at least 3 frames.
    ValueError
        If ``max_bases`` is not a positive integer.
    """
    if isinstance(max_bases, bool) or not isinstance(max_bases, (int, np.integer)):
        raise ValueError(f"max_bases must be a positive integer, got {max_bases!r}")
    if max_bases < 1:
        raise ValueError(f"max_bases must be a positive integer, got {max_bases!r}")
    W = _check_measurements(W)
    return _n_bases_from_spectrum(spectrum(W).singular, W.shape, int(max_bases))


# ----------------------------------------------------------------------------------------
# Rigid: Tomasi-Kanade
# ----------------------------------------------------------------------------------------


def _metric_constraints(Pi: np.ndarray) -> np.ndarray:
    """Orthonormality constraints on Q for every frame, as rows acting on svec(Q).

    Frame f, with rows ``a = Pi[2f]`` and ``b = Pi[2f + 1]``, requires
    ``a Q a^T - b Q b^T = 0`` and ``a Q b^T = 0`` (equal row norms, orthogonal rows of the
    corrected block). Both are Frobenius products ``<M, Q>`` with the symmetric matrices
    ``a a^T - b b^T`` and ``(a b^T + b a^T) / 2``, hence rows ``svec(M)``.

    Parameters
    ----------
    Pi : ndarray of shape (..., 2F, n)
        One motion factor or a stack of them.

    Returns
    -------
    ndarray of shape (..., 2F, n (n + 1) / 2)
        Rows 2f (equal norms) and 2f + 1 (orthogonality) belong to frame f.
    """
    a, b = Pi[..., 0::2, :], Pi[..., 1::2, :]
    equal_norms = np.einsum("...fi,...fj->...fij", a, a) - np.einsum("...fi,...fj->...fij", b, b)
    orthogonal = np.einsum("...fi,...fj->...fij", a, b)
    orthogonal = 0.5 * (orthogonal + np.swapaxes(orthogonal, -1, -2))
    rows = np.stack([_svec(equal_norms), _svec(orthogonal)], axis=-2)
    return rows.reshape(*Pi.shape[:-1], rows.shape[-1])


def rigid_from_factor(M: np.ndarray) -> np.ndarray:
    """Metric upgrade of rank-3 motion factors into rotations.

    The corrective Q = G G^T solves the orthonormality constraints of every frame in the
    least-squares sense (see :func:`rigid_rotations`).

    Parameters
    ----------
    M : ndarray of shape (2F, 3) or (B, 2F, 3)
        One motion factor, or a stack of B (e.g. one per window of frames).

    Returns
    -------
    ndarray of shape (F, 2, 3) or (B, F, 2, 3)
    """
    stacked = M if M.ndim == 3 else M[None]
    constraints = _metric_constraints(stacked)
    # Homogeneous least squares: Q is the right singular vector of the smallest singular
    # value. No per-frame scale is imposed, so scaled-orthographic data (zoom) work as well.
    _, _, Vt = np.linalg.svd(constraints, full_matrices=False)
    rows, cols, weights = _svec_indices(3)
    Q = np.zeros((stacked.shape[0], 3, 3))
    Q[:, rows, cols] = Vt[:, -1] / weights
    Q[:, cols, rows] = Vt[:, -1] / weights
    Q *= np.where(np.trace(Q, axis1=1, axis2=2) < 0.0, -1.0, 1.0)[:, None, None]
    eigenvalues, eigenvectors = np.linalg.eigh(Q)
    # Eigen-clip: noise can make the least-squares Q slightly indefinite.
    G = eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))[:, None, :]
    rotations = project_to_stiefel((stacked @ G).reshape(stacked.shape[0], -1, 2, 3))
    return rotations if M.ndim == 3 else rotations[0]


def _rigid_from_spectrum(spectrum: Spectrum) -> np.ndarray:
    """Tomasi-Kanade rotations from the spectrum of W (motion factor ``U_3 S_3^{1/2}``)."""
    return rigid_from_factor(spectrum.left[:, :3] * np.sqrt(spectrum.singular[:3]))


def rigid_rotations(W: np.ndarray) -> np.ndarray:
    """Camera rotations of a rigid object (Tomasi and Kanade, IJCV 1992).

    ``W ~ M B`` at rank 3 (``M = U_3 S_3^{1/2}``); the corrective 3 x 3 matrix G makes every
    frame block ``M_f G`` a scaled rotation. With ``Q = G G^T`` the conditions are linear:
    ``m_2f Q m_2f^T = m_2f+1 Q m_2f+1^T`` and ``m_2f Q m_2f+1^T = 0``; Q spans their
    (least-squares) null space, is clipped to PSD, ``G = V Lambda^{1/2}``, and each
    ``M_f G`` is projected to the nearest matrix with orthonormal rows. The scale of Q is
    free: the projection divides it out, which also admits a per-frame zoom.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Row-centred measurements, F >= 3 and P >= 4.

    Returns
    -------
    ndarray of shape (F, 2, 3), float64
        Rotations with orthonormal rows, up to one global rotation and reflection.

    Raises
    ------
    MeasurementError
        If W has an odd number of rows, non-finite values, fewer than 3 frames or fewer
        than 4 points.
    """
    W = _check_measurements(W)
    _check_n_bases(1, W.shape[0] // 2, W.shape[1])
    return _rigid_from_spectrum(spectrum(W))


# ----------------------------------------------------------------------------------------
# Non-rigid: Dai, Li and He's intersection of the PSD cone with the constraint null space
# ----------------------------------------------------------------------------------------


def _null_space(constraints: np.ndarray, dimension: int) -> np.ndarray:
    """Orthonormal basis (columns) of the numerical null space of a constraint matrix.

    With noise the constraints have full column rank; the ``dimension`` right singular
    vectors of the smallest singular values span the space "nearest" to the noise-free null
    space. Directions whose singular value is at rounding level are always included, so a
    larger exact null space (e.g. K above the rank of W) is never cut arbitrarily.

    Parameters
    ----------
    constraints : ndarray of shape (m, d)
    dimension : int
        Expected dimension of the null space.

    Returns
    -------
    ndarray of shape (d, r), r >= dimension
    """
    n_unknowns = constraints.shape[1]
    # The full V is needed only when there are fewer equations than unknowns; a full U
    # (2F x 2F) is never needed.
    _, singular, Vt = np.linalg.svd(constraints, full_matrices=constraints.shape[0] < n_unknowns)
    singular = np.concatenate([singular, np.zeros(n_unknowns - singular.size)])
    exact = int(np.count_nonzero(singular <= 1e-12 * singular[0]))
    dimension = min(max(dimension, exact), n_unknowns)
    return Vt[n_unknowns - dimension :].T


def _min_trace_psd(
    basis: np.ndarray,
    normal: np.ndarray,
    n: int,
    *,
    tol: float = _ADMM_TOL,
    max_iter: int = _ADMM_MAX_ITER,
) -> tuple[np.ndarray, bool]:
    """Smallest-trace PSD matrix in a linear space with one normalisation, by ADMM.

    Solves ``min tr(Q)`` subject to ``svec(Q) in span(basis)``, ``<N, Q> = 1`` and
    ``Q >= 0`` (PSD), with ``svec(N) = normal``. ADMM on the split ``X = Z`` with
    ``X`` in the affine set and ``Z`` in the PSD cone (scaled dual ``Y``, penalty ``rho``):

    * ``X = Proj_affine(Z - Y - I / rho)`` (the prox of the linear objective),
    * ``Z = Proj_PSD(X + Y)`` (eigenvalue clipping),
    * ``Y = Y + X - Z``,

    with ``rho`` rebalanced when the primal and dual residuals differ by more than 10x
    (Boyd et al., "Distributed optimization ... ADMM", 2011, section 3.4.1). The affine
    projection is exact and cheap because ``basis`` is orthonormal: project on its span,
    then on the hyperplane ``<N, Q> = 1`` inside it.

    Parameters
    ----------
    basis : ndarray of shape (n (n + 1) / 2, r)
        Orthonormal svec coordinates of the linear space.
    normal : ndarray of shape (n (n + 1) / 2,)
        svec of the normalisation matrix N.
    n : int
        Size of Q.
    tol : float
        Relative tolerance on the primal and dual residuals.
    max_iter : int
        Iteration cap.

    Returns
    -------
    Q : ndarray of shape (n, n)
        The PSD iterate Z at termination (zero if the normalisation is orthogonal to the
        space).
    converged : bool
        Whether both residuals fell below ``tol``.
    """
    g = basis.T @ normal
    g_norm2 = float(g @ g)
    if g_norm2 <= 1e-300:
        return np.zeros((n, n)), False
    identity = _svec(np.eye(n))

    def project_affine(v: np.ndarray) -> np.ndarray:
        y = basis.T @ v
        y += (1.0 - g @ y) / g_norm2 * g
        return basis @ y

    # Start from the affine point nearest to the origin; its PSD projection seeds Z.
    x = project_affine(np.zeros_like(normal))
    z = _svec(_project_psd(_smat(x, n)))
    y = np.zeros_like(z)
    rho = 1.0
    for _ in range(max_iter):
        x = project_affine(z - y - identity / rho)
        z_old = z
        z = _svec(_project_psd(_smat(x + y, n)))
        y += x - z
        primal = np.linalg.norm(x - z)
        dual = rho * np.linalg.norm(z - z_old)
        if primal <= tol * max(np.linalg.norm(x), np.linalg.norm(z)) and dual <= tol * max(
            rho * np.linalg.norm(y), 1.0
        ):
            return _smat(z, n), True
        if primal > 10.0 * dual:
            rho *= 2.0
            y /= 2.0
        elif dual > 10.0 * primal:
            rho /= 2.0
            y *= 2.0
    return _smat(z, n), False


def _skew(w: np.ndarray) -> np.ndarray:
    """Cross-product matrices: (..., 3) -> (..., 3, 3) with ``skew(w) x = w x x``."""
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


# Generators of so(3): _GENERATORS[j] = skew(e_j).
_GENERATORS = _skew(np.eye(3))


def _exp_so3(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rodrigues' exponential and its right Jacobian for a stack of rotation vectors.

    Parameters
    ----------
    w : ndarray of shape (F, 3)
        Rotation vectors (radians).

    Returns
    -------
    rotation : ndarray of shape (F, 3, 3)
        ``exp(skew(w))``.
    right_jacobian : ndarray of shape (F, 3, 3)
        ``J_r(w)`` with ``exp(skew(w + d)) = exp(skew(w)) exp(skew(J_r(w) d))`` to first
        order in d.
    """
    theta = np.linalg.norm(w, axis=-1)[:, None, None]
    S = _skew(w)
    S2 = S @ S
    # (1 - cos t) / t^2 and (t - sin t) / t^3 cancel catastrophically for small t (about
    # 8 digits lost at 1e-4 rad); below that their two-term Taylor series are exact to
    # rounding. L-BFGS starts at w = 0, so this branch is always taken once.
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    c = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (t - np.sin(t)) / t**3)
    identity = np.eye(3)
    return identity + a * S + b * S2, identity - b * S + c * S2


class _MotionFit:
    """Misfit of rotations to a motion factor under the corrective-triple model.

    For a motion factor Pi (2F x n) the model says ``Pi_f G_k = c_fk R_f`` for k column
    triples ``G_k`` (n x 3) and coefficients ``c_fk``. For given rotations the best triples
    and coefficients are found in closed form: with ``g_k = vec(G_k)`` orthonormal (which
    excludes ``G = 0``) and ``c_fk = <Pi_f G_k, R_f> / 2``,

    ``misfit(R) = min sum_fk ||Pi_f G_k - c_fk R_f||_F^2 = sum of the k smallest
    eigenvalues of H(R) = sum_f L_f^T (I - r_f r_f^T) L_f``,

    where ``L_f g = vec(Pi_f G)`` and ``r_f = vec(R_f) / sqrt(2)``. This couples every
    fitted triple to the same rotation, which Dai et al.'s single-triple equations do not:
    those leave the rotations free to first order along ``G_k + sum_j G_j omega_j``
    (omega_j skew), so that even 0.01 % noise gave 5-10 degree errors for K = 3, 4 in our
    measurements. The eigenvalues of H beyond the k-th tell how well further triples would
    fit (see :func:`_intersection_with`).
    """

    def __init__(self, Pi: np.ndarray, n_triples: int) -> None:
        n_frames, n = Pi.shape[0] // 2, Pi.shape[1]
        self.n_triples = n_triples
        self.blocks = Pi.reshape(n_frames, 2, n)
        # sum_f L_f^T L_f = I_3 (x) Pi^T Pi in the (m, b) ordering of vec(G).
        self.lifted_gram = np.kron(Pi.T @ Pi, np.eye(3))

    def evaluate(
        self, R: np.ndarray, *, spectrum: bool = True
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """Misfit, its Euclidean gradient with respect to R, and the spectrum of H.

        Parameters
        ----------
        R : ndarray of shape (F, 2, 3)
        spectrum : bool, default True
            Whether all eigenvalues of H are wanted. False computes only the k smallest
            eigenpairs (all the misfit and gradient need; a partial eigensolver, about half
            the cost of the full one at 3n = 90) and returns just those k eigenvalues.

        Returns
        -------
        misfit : float
        gradient : ndarray of shape (F, 2, 3)
            ``-2 sum_k c_fk Pi_f G_k`` (the eigenvectors are stationary, so only the
            explicit dependence on R counts).
        eigenvalues : ndarray of shape (3n,)
            Eigenvalues of H, increasing.
        """
        n_frames, n = self.blocks.shape[0], self.blocks.shape[2]
        r = R / math.sqrt(2.0)
        # L_f^T r_f, i.e. Pi_f^T r_f flattened in the (m, b) order of vec(G).
        projected = np.einsum("fim,fib->fmb", self.blocks, r).reshape(n_frames, 3 * n)
        H = self.lifted_gram - projected.T @ projected
        if spectrum:
            eigenvalues, eigenvectors = np.linalg.eigh(H)
        else:
            eigenvalues, eigenvectors = scipy.linalg.eigh(
                H, subset_by_index=[0, self.n_triples - 1], driver="evr", check_finite=False
            )
        triples = eigenvectors[:, : self.n_triples].reshape(n, 3, -1)
        # Pi_f G_k for every frame and triple, (F, k, 2, 3).
        blocks = np.einsum("fim,mbk->fkib", self.blocks, triples, optimize=True)
        coefficients = np.einsum("fkib,fib->fk", blocks, r) / math.sqrt(2.0)
        gradient = -2.0 * np.einsum("fk,fkib->fib", coefficients, blocks)
        return float(eigenvalues[: self.n_triples].sum()), gradient, eigenvalues

    def triples(self, R: np.ndarray) -> np.ndarray:
        """The best corrective triples for rotations R, shape (n, 3, k) (``G_k = [..., k]``)."""
        n_frames, n = self.blocks.shape[0], self.blocks.shape[2]
        r = R / math.sqrt(2.0)
        projected = np.einsum("fim,fib->fmb", self.blocks, r).reshape(n_frames, 3 * n)
        _, eigenvectors = np.linalg.eigh(self.lifted_gram - projected.T @ projected)
        return eigenvectors[:, : self.n_triples].reshape(n, 3, -1)


def _refine_rotations(
    fit: _MotionFit, R: np.ndarray, *, tol: float, max_iter: int
) -> tuple[np.ndarray, float, np.ndarray]:
    """Minimise the misfit of :class:`_MotionFit` over the rotations, starting from R.

    The rotations are parametrised around the start as ``R_f exp(skew(w_f))`` (full 3 x 3
    rotations completed by the cross product, of which the first two rows are used), and
    the 3F rotation vectors are optimised by L-BFGS. Alternating between the triples and
    the rotations also decreases the misfit but, being a block coordinate descent on a
    bilinear problem, needed thousands of sweeps; L-BFGS needs tens to a few hundred
    iterations of O(F K^3) each.

    Parameters
    ----------
    fit : _MotionFit
    R : ndarray of shape (F, 2, 3)
        Starting rotations.
    tol : float
        Relative decrease of the misfit (from its starting value) at which to stop.
    max_iter : int
        Iteration budget.

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    misfit : float
    eigenvalues : ndarray of shape (3n,)
        Spectrum of H at the result; a clear gap after the K-th eigenvalue means the model
        fits.
    """
    start = np.concatenate([R, np.cross(R[:, 0], R[:, 1])[:, None]], axis=1)

    def rotations_at(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        exponential, right_jacobian = _exp_so3(x.reshape(-1, 3))
        return (start @ exponential)[:, :2], right_jacobian

    initial_misfit, _, initial_spectrum = fit.evaluate(R)
    if initial_misfit <= 0.0:
        return R, initial_misfit, initial_spectrum

    def misfit_and_gradient(x: np.ndarray) -> tuple[float, np.ndarray]:
        rotations, right_jacobian = rotations_at(x)
        misfit, gradient, _ = fit.evaluate(rotations, spectrum=False)
        # d R / d w_j = R skew(J_r e_j): project the Euclidean gradient on R skew(e_i), then
        # apply J_r^T.
        body = np.einsum(
            "fia,fjia->fj", gradient, np.einsum("fib,jba->fjia", rotations, _GENERATORS)
        )
        gradient_w = np.einsum("fij,fi->fj", right_jacobian, body).reshape(-1)
        # L-BFGS-B stops on (f_k - f_k+1) / max(|f_k|, |f_k+1|, 1) <= ftol, an absolute test
        # for f < 1; relative to the starting misfit the test stays relative down to the
        # noise floor (without noise it stopped at 0.2 degrees instead of 1e-4).
        return misfit / initial_misfit, gradient_w / initial_misfit

    result = minimize(
        misfit_and_gradient,
        np.zeros(3 * R.shape[0]),
        jac=True,
        method="L-BFGS-B",
        options={"maxiter": max_iter, "ftol": tol, "gtol": 0.0, "maxcor": 20},
    )
    rotations = project_to_stiefel(rotations_at(result.x)[0])
    misfit, _, eigenvalues = fit.evaluate(rotations)
    return rotations, misfit, eigenvalues


def fit_rotations_to_shapes(
    rotations: np.ndarray, tracks: np.ndarray, shapes: np.ndarray, iterations: int = 5
) -> np.ndarray:
    """Camera rotations that best project given 3D shapes onto the tracks, from a start.

    Minimises ``sum_f ||W_f - R_f S_f||_F^2`` over rotations R_f with orthonormal rows (an
    unbalanced orthogonal Procrustes problem per frame, without a closed form) by
    Gauss-Newton steps on ``R_f exp(skew(w_f))``: with ``M_f = S_f S_f^T`` and
    ``G_f = W_f S_f^T - R_f M_f`` the step solves ``H_f w_f = g_f`` with
    ``H_ab = tr((R_f E_a)^T R_f E_b M_f)`` and ``g_a = <R_f E_a, G_f>`` (E_a the generators of
    so(3)). The cost in the number of points is the two 3 x 3 and 2 x 3 products per frame.
    Used by the ADMM loop to refine approximate rotations (the windowed estimate) with the
    shapes (see :func:`moju_core.admm.run`).

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
        Starting rotations (orthonormal rows).
    tracks : ndarray of shape (F, 2, P)
        Centred tracks W_f.
    shapes : ndarray of shape (F, 3, P)
        Shapes S_f.
    iterations : int, default 5
        Gauss-Newton steps (each frame's problem has 3 unknowns and converges in a few).

    Returns
    -------
    ndarray of shape (F, 2, 3)
        Rotations with orthonormal rows.
    """
    full = np.concatenate([rotations, np.cross(rotations[:, 0], rotations[:, 1])[:, None]], axis=1)
    moments = np.einsum("fip,fjp->fij", shapes, shapes)  # M_f = S_f S_f^T, (F, 3, 3)
    cross = np.einsum("fip,fjp->fij", tracks, shapes)  # W_f S_f^T, (F, 2, 3)
    for _ in range(iterations):
        R = full[:, :2]
        directions = np.einsum("fij,ajk->faik", R, _GENERATORS)  # R_f E_a, (F, 3, 2, 3)
        gradient = cross - R @ moments
        g = np.einsum("faik,fik->fa", directions, gradient)
        H = np.einsum("faik,fkl,fbil->fab", directions, moments, directions)
        H += 1e-12 * np.trace(H, axis1=1, axis2=2)[:, None, None] * np.eye(3)
        step = np.linalg.solve(H, g[:, :, None])[:, :, 0]
        full = full @ _exp_so3(step)[0]
    return project_to_stiefel(full[:, :2])


def _synchronise_signs(rotations: np.ndarray, W: np.ndarray, gram: np.ndarray | None) -> np.ndarray:
    """Flip frames so that their back-projected shapes agree with the dominant shape.

    ``Pi_hat_f G_k = c_fk R_f`` fixes R_f only up to the sign of ``c_fk``, and under a
    linear shape model ``(-R_f, -S_f)`` explains ``W_f`` as well as ``(R_f, S_f)``. The
    sign is chosen by assuming one dominant shape (a mean shape, as in faces, bodies and
    cloth): the back-projections ``X_f = R_f^T W_f`` (3 x P) of all frames should correlate
    positively. The signs of the top eigenvector of their Gram matrix
    ``H_fg = <X_f, X_g> = sum_ij (R_f R_g^T)_ij (W_f W_g^T)_ij`` are the spectral
    relaxation of this +-1 synchronisation; H comes from the 2 x 2 blocks of ``W W^T``
    when that is at hand, without touching the P points again.

    Parameters
    ----------
    rotations : ndarray of shape (F, 2, 3)
    W : ndarray of shape (2F, P)
    gram : ndarray of shape (2F, 2F) or None
        ``W W^T`` if already computed.

    Returns
    -------
    ndarray of shape (F, 2, 3)
        The rotations with some frames negated.
    """
    n_frames = rotations.shape[0]
    if gram is not None:
        blocks = gram.reshape(n_frames, 2, n_frames, 2)
        H = np.einsum("fia,gja,figj->fg", rotations, rotations, blocks, optimize=True)
    else:
        back_projected = np.einsum("fia,fip->fap", rotations, W.reshape(n_frames, 2, -1))
        back_projected = back_projected.reshape(n_frames, -1)
        if back_projected.shape[0] > back_projected.shape[1]:
            # Long sequences of few points: the top eigenvector of H = X X^T is X v for the
            # top eigenvector v of the smaller X^T X (3P x 3P), O(F P^2) instead of O(F^3).
            _, right = np.linalg.eigh(back_projected.T @ back_projected)
            top = back_projected @ right[:, -1]
            return rotations * np.where(top >= 0.0, 1.0, -1.0)[:, None, None]
        H = back_projected @ back_projected.T
    _, eigenvectors = np.linalg.eigh(H)
    signs = np.where(eigenvectors[:, -1] >= 0.0, 1.0, -1.0)
    return rotations * signs[:, None, None]


def _intersection_from_spectrum(
    W: np.ndarray, spectrum: Spectrum, n_bases: int, seed: int
) -> np.ndarray:
    """Body of :func:`intersection_rotations` for a validated W and its spectrum."""
    s = spectrum.singular
    if s[0] <= 0.0:
        raise MeasurementError("W is zero after centring: the points do not move in the image")
    # A basis beyond the exact rank of W (a rank-deficient W, e.g. a K too large for
    # noise-free data) has only rounding errors in its columns of Pi_hat: no triple there is a
    # scaled rotation.
    exact_rank = int(np.count_nonzero(s > _RANK_FLOOR * s[0]))
    supported = max(1, math.ceil(exact_rank / 3))
    if n_bases > supported:
        warnings.warn(
            f"n_bases={n_bases} exceeds what W supports: W has rank {exact_rank}, enough "
            f"for {supported} shape bases; using n_bases={supported}",
            RuntimeWarning,
            stacklevel=3,
        )
        n_bases = supported
    # Likewise for the directions that stand above the noise (the rule of choose_n_bases):
    # a triple in the noise cannot be fitted, and trying it only adds local minima.
    significant = significant_rank(s, W.shape)
    supported = max(1, math.ceil(significant / 3))
    if n_bases > supported:
        warnings.warn(
            f"n_bases={n_bases} exceeds what W supports above its noise: {significant} "
            f"singular values stand above the noise level, enough for {supported} shape "
            f"bases; using n_bases={supported}",
            RuntimeWarning,
            stacklevel=3,
        )
        n_bases = supported
    # A degenerate relaxation (Q of rank below 3, e.g. a camera that never tilts) is
    # retried with one basis fewer, down to the rigid method.
    for k in range(n_bases, 1, -1):
        rotations, failure = _intersection_with(W, spectrum, k, seed)
        if failure is None:
            return rotations
        fallback = f"n_bases={k - 1}" if k > 2 else "rigid (Tomasi-Kanade) rotations"
        warnings.warn(
            f"intersection rotations with n_bases={k} failed: {failure}; trying {fallback}",
            RuntimeWarning,
            stacklevel=3,
        )
    return _rigid_from_spectrum(spectrum)


def _noise_variance(s: np.ndarray, shape: tuple[int, int], rank: int) -> float:
    """Variance of white noise in the entries of W, from its singular values beyond ``rank``.

    Noise of variance sigma^2 puts about ``sigma^2 (m - r)(M - r)`` of energy into the
    ``m - r`` trailing directions of an m x M matrix (m <= M) whose signal has rank r. Without
    noise the result is a rounding error (or, for a W that is only approximately of rank r,
    the energy of the neglected directions spread the same way).
    """
    m, M = min(shape), max(shape)
    if rank >= m:
        return 0.0
    return float(np.sum(s[rank:m] ** 2) / ((m - rank) * (M - rank)))


def noise_variance(singular_values: np.ndarray, shape: tuple[int, int]) -> float:
    """Variance of white noise in the entries of a matrix, from its singular values.

    The singular values above the Gavish-Donoho threshold are signal (the rule of
    :func:`choose_n_bases`); the energy of the others is spread as white noise would spread
    it (see :func:`_noise_variance`).

    Parameters
    ----------
    singular_values : ndarray of shape (min(shape),)
        Singular values of the matrix, decreasing.
    shape : (int, int)
        Its shape, e.g. (2F, P) for the measurements.

    Returns
    -------
    float
        sigma^2, in squared units of the entries (0 for noise-free low-rank data, up to
        rounding).
    """
    return _noise_variance(singular_values, shape, significant_rank(singular_values, shape))


def _relaxation_starts(Pi: np.ndarray, seed: int) -> tuple[list[np.ndarray] | None, np.ndarray]:
    """Dai et al.'s rotations (steps 1-3) and further starting points from their Q.

    Returns the starting rotations, the first being Dai et al.'s estimate from the top-3
    factor of Q, and Q's eigenvalues (decreasing); None instead of the starts when Q has
    rank below 3.
    """
    n = Pi.shape[1]
    # The noise-free solution space has dimension 2K^2 - K for n = 3K (Akhter et al.); for
    # n < 3K (a basis cut by the noise) the formula with K = ceil(n / 3) still spans it.
    k = math.ceil(n / 3)
    basis = _null_space(_metric_constraints(Pi), 2 * k**2 - k)
    # Normalise with all frames together, tr(Pi Q Pi^T) = 1, so that no single frame (the
    # first frame's block = I of the paper) has to be well conditioned.
    Q, _ = _min_trace_psd(basis, _svec(Pi.T @ Pi), n)
    eigenvalues, eigenvectors = np.linalg.eigh(Q)
    eigenvalues, eigenvectors = eigenvalues[::-1], eigenvectors[:, ::-1]
    if eigenvalues[0] <= 0.0 or eigenvalues[2] < _DEGENERATE_EIGEN_RATIO * eigenvalues[0]:
        return None, eigenvalues
    # Under noise, or for a basis weak against the unmodelled deformation, Q is not of rank 3
    # (eigenvalues 1, .6, .5, .3, .2, ...); random 3-dim subspaces of its top eigenspace
    # are further starts, which reached the right minimum of the joint fit when the top-3
    # factor led into a wrong one.
    scaled = eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))
    width = min(n, _SUBSPACE_WIDTH)
    rng = np.random.default_rng(seed)
    factors = [scaled[:, :3]] + [
        scaled[:, :width] @ np.linalg.qr(rng.standard_normal((width, 3)))[0]
        for _ in range(_SUBSPACE_STARTS)
    ]
    return [project_to_stiefel((Pi @ G).reshape(-1, 2, 3)) for G in factors], eigenvalues


def _intersection_with(
    W: np.ndarray, spectrum: Spectrum, n_bases: int, seed: int
) -> tuple[np.ndarray | None, str | None]:
    """Intersection rotations with at most ``n_bases >= 2`` bases.

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3) or None
        None when the relaxation is degenerate.
    failure : str or None
        Why the estimate was rejected.
    """
    U, s = spectrum.left, spectrum.singular
    # The joint fit works in every direction of W above the noise, and in at least Dai et
    # al.'s 3K: the corrective triples of approximately low-rank data (e.g. faces, whose
    # expressions are not exact xyz bases) are exact only in all significant directions, and
    # cutting at 3K of them biased the fit by 4-23 degrees; a basis that sinks partly below
    # the noise still needs its 3 directions. The relaxation that starts the fit keeps the
    # rank-3K factorisation of Dai et al.
    exact_rank = int(np.count_nonzero(s > _RANK_FLOOR * s[0]))
    n_start = min(3 * n_bases, exact_rank)
    n = min(max(significant_rank(s, W.shape), n_start), exact_rank, _MAX_FIT_RANK)
    # Everything below works on matrices of a few dozen rows and columns, where BLAS threads
    # only add synchronisation (on a loaded machine, 10x slower than one thread).
    with threadpool_limits(limits=1):
        # Dai et al.'s symmetric split; dividing by s_1 makes the problem independent of the
        # units of W (Q is then O(1), which the ADMM penalty rho = 1 assumes).
        starts, eigenvalues = _relaxation_starts(U[:, :n_start] * np.sqrt(s[:n_start] / s[0]), seed)
        if starts is None:
            return None, (
                f"the trace-minimal Q has rank below 3 (top eigenvalues "
                f"{np.array2string(eigenvalues[:4], precision=3)})"
            )
        starts.append(_rigid_from_spectrum(spectrum))
        frames = _fit_frames(W.shape[0] // 2)
        rows = (2 * frames[:, None] + np.arange(2)).reshape(-1)
        rotations, n_exact, excess, fit, weights = _fit_triples(
            W.shape, U[rows, :n], s, n_bases, [start[frames] for start in starts]
        )
        if len(frames) < W.shape[0] // 2:
            rotations = _rotations_from_triples(fit.triples(rotations), U[:, :n] * weights)
    if n_exact == 0:
        warnings.warn(
            f"no corrective triple fits W within its noise (the best triple's misfit is "
            f"{excess:.3g} times what the noise of W explains): the deformation does not "
            f"follow the low-rank shape model, and the rotations (the best single-triple fit) "
            f"may be inaccurate",
            RuntimeWarning,
            stacklevel=4,
        )
    return _synchronise_signs(rotations, W, spectrum.gram), None


def _fit_triples(
    shape: tuple[int, int],
    U: np.ndarray,
    s: np.ndarray,
    max_triples: int,
    starts: list[np.ndarray],
) -> tuple[np.ndarray, int, float]:
    """Joint fit of as many corrective triples as the data hold exactly.

    For k = 1, 2, ..., ``max_triples`` the rotations are fitted to k triples of the motion
    factor ``U S^(1/2)`` (:class:`_MotionFit`), continuing from the fit with k - 1 triples
    (the first from Dai et al.'s estimate, ``starts[0]``). The k-th triple is then tested:
    exact when its misfit under ``U S`` is at most ``_EXACT_NOISE_RATIO`` times what the noise
    of W explains, or at rounding level. If it is not, every start is searched too (unless
    the continued fit is exact beyond doubt, ``_LINEAGE_EXACT``), a clearly lower misfit
    (``_LINEAGE_MARGIN``) replaces the continued fit, and the test is repeated. The first
    inexact triple ends the loop: fitting a triple that the data hold only approximately
    pulls the rotations towards it (4-23 degrees on the project's faces). The last exact
    fit is searched once more if it was not yet, and refined under ``U S``.

    Parameters
    ----------
    shape : (int, int)
        Shape of W.
    U : ndarray of shape (2F, n)
        Leading left singular vectors of W.
    s : ndarray
        All singular values of W, decreasing.
    max_triples : int
    starts : list of ndarray of shape (F, 2, 3)

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3)
    n_exact : int
        Number of exact triples (0 when not even one triple fits; the rotations are then
        the best fit of one triple).
    excess : float
        Misfit of the first inexact triple over the noise level (huge without noise).
    fit : _MotionFit
        The last fit (of the rows of U given).
    weights : ndarray of shape (n,)
        The column weights of its motion factor, ``U * weights``.
    """
    n_frames, n = U.shape[0] // 2, U.shape[1]
    sigma2 = _noise_variance(s, shape, n)
    # Misfit of one triple from the noise alone, in the units of the test factor below: the
    # 2 x 3 block of a unit triple carries noise of total variance 2 sigma^2 / s_1^2 in every
    # frame (fitting c_fk and the rotations absorbs a little of it: 0.6-1.2 times this was
    # measured at the true rotations of exactly low-rank sequences).
    noise_floor = 2.0 * n_frames * sigma2 / s[0] ** 2
    # Dai et al.'s split U S^(1/2) for the fit: its basins of attraction were the widest in
    # our tests (U S and, above all, U alone led the search into wrong minima far more often).
    motion = U * np.sqrt(s[:n] / s[0])
    # White noise adds the same misfit to every triple of U S: the factor for the test.
    test_motion = U * (s[:n] / s[0])
    # Misfits below this are rounding errors (the eigenvalues of H are at most 1).
    tie = 1e-12

    def is_exact(rotations: np.ndarray, eigenvalues: np.ndarray, k: int) -> tuple[bool, float]:
        if eigenvalues[k - 1] <= _EXACT_RELATIVE * eigenvalues[-1]:
            return True, 0.0
        excess = _MotionFit(test_motion, k).evaluate(rotations)[2][k - 1] / max(noise_floor, 1e-300)
        return excess <= _EXACT_NOISE_RATIO, excess

    def search(
        fit: _MotionFit, rotations: np.ndarray, misfit: float, eigenvalues: np.ndarray
    ) -> tuple[np.ndarray, float, np.ndarray]:
        """Replace a fit by the best fit from all starts if that is clearly lower."""
        candidates = [
            _refine_rotations(fit, start, tol=_SEARCH_TOL, max_iter=_SEARCH_MAX_ITER)
            for start in starts
        ]
        candidate = min(candidates, key=lambda c: c[1])
        if candidate[1] + tie < _LINEAGE_MARGIN * (misfit + tie):
            return _refine_rotations(fit, candidate[0], tol=_REFINE_TOL, max_iter=_REFINE_MAX_ITER)
        return rotations, misfit, eigenvalues

    chosen = None  # (fit, k, searched, rotations, misfit, eigenvalues) of the last exact k
    n_exact, excess, previous = 0, math.inf, starts[0]
    for k in range(1, max_triples + 1):
        fit = _MotionFit(motion, k)
        rotations, misfit, eigenvalues = _refine_rotations(
            fit, previous, tol=_REFINE_TOL, max_iter=_REFINE_MAX_ITER
        )
        exact, excess = is_exact(rotations, eigenvalues, k)
        searched = not exact and misfit > _LINEAGE_EXACT * eigenvalues[k]
        if searched:
            rotations, misfit, eigenvalues = search(fit, rotations, misfit, eigenvalues)
            exact, excess = is_exact(rotations, eigenvalues, k)
        if chosen is None or exact:
            # Without any exact triple, the best single-triple fit is kept.
            chosen = (fit, k, searched, rotations, misfit, eigenvalues)
        if not exact:
            break
        n_exact, previous = k, rotations
    fit, k, searched, rotations, misfit, eigenvalues = chosen
    if not searched and misfit > _LINEAGE_EXACT * eigenvalues[k]:
        rotations, _, _ = search(fit, rotations, misfit, eigenvalues)
    # Dai et al.'s split weighs the weak directions up against the noise (by (s_1 / s_j)^1/2);
    # the same fit with U S, under which noise adds the same to every triple, was the more
    # accurate one in our tests (1-3.5 against 4-7 degrees at 3-5.5 % noise). Without noise
    # an exact fit is exact under any weighting and stays where it is. A single triple is
    # not refined so: it fixes the rotations only weakly along the other (nearly exact)
    # triples, and U S, which makes the weak directions count less, let them drift (from 0.7
    # to 17 degrees on face4 with 1 % noise).
    weights = np.sqrt(s[:n] / s[0])
    if k > 1:
        fit, weights = _MotionFit(test_motion, k), s[:n] / s[0]
        rotations, _, _ = _refine_rotations(
            fit, rotations, tol=_REFINE_TOL, max_iter=_REFINE_MAX_ITER
        )
    return rotations, n_exact, excess, fit, weights


def _fit_frames(n_frames: int) -> np.ndarray:
    """Frames the joint fit of the triples uses: all, or _MAX_FIT_FRAMES spread evenly."""
    if n_frames <= _MAX_FIT_FRAMES:
        return np.arange(n_frames)
    return np.unique(np.linspace(0, n_frames - 1, _MAX_FIT_FRAMES).round().astype(np.int64))


def _rotations_from_triples(
    triples: np.ndarray, motion: np.ndarray, sweeps: int = 20
) -> np.ndarray:
    """Every frame's rotation from corrective triples fitted on a subset of the frames.

    The triples ``G_k`` do not depend on the frame: frame f's rotation maximises
    ``sum_k <Pi_f G_k, R_f>^2`` (the misfit of :class:`_MotionFit` for fixed triples), found
    by the fixed-point iteration ``R_f <- polar(sum_k <Pi_f G_k, R_f> Pi_f G_k)`` from the
    polar factor of the frame's strongest block; each sweep increases the objective. O(F k n)
    in all; the sign of each frame is left to :func:`_synchronise_signs`.

    Parameters
    ----------
    triples : ndarray of shape (n, 3, k)
        The fitted triples (:meth:`_MotionFit.triples`).
    motion : ndarray of shape (2F, n)
        The motion factor of all frames, weighted as the fit's.
    sweeps : int
        Fixed-point iterations.

    Returns
    -------
    ndarray of shape (F, 2, 3)
    """
    n_frames = motion.shape[0] // 2
    blocks = np.einsum(
        "fim,mbk->fkib", motion.reshape(n_frames, 2, -1), triples, optimize=True
    )  # Pi_f G_k, (F, k, 2, 3)
    strongest = np.argmax(np.einsum("fkib,fkib->fk", blocks, blocks), axis=1)
    rotations = project_to_stiefel(blocks[np.arange(n_frames), strongest])
    for _ in range(sweeps):
        coefficients = np.einsum("fkib,fib->fk", blocks, rotations)
        rotations = project_to_stiefel(np.einsum("fk,fkib->fib", coefficients, blocks))
    return rotations


def intersection_rotations(W: np.ndarray, n_bases: int, *, seed: int = 0) -> np.ndarray:
    """Camera rotations of a deforming object by Dai, Li and He's prior-free method.

    1. Rank-3K factorisation ``W ~ Pi_hat B_hat`` with the singular values split evenly,
       ``Pi_hat = U_3K S_3K^{1/2}`` (only Pi_hat is needed).
    2. Every frame gives ``pi_2f Q pi_2f^T - pi_2f+1 Q pi_2f+1^T = 0`` and
       ``pi_2f Q pi_2f+1^T = 0`` for ``Q = G_k G_k^T`` (3K x 3K). The noise-free solutions
       form a space of dimension ``2K^2 - K``; with noise it is taken as the span of the
       right singular vectors of the smallest singular values of the constraint matrix.
    3. Q is the PSD matrix of smallest trace in that space, normalised by
       ``tr(Pi_hat Q Pi_hat^T) = 1``, found by ADMM (:func:`_min_trace_psd`);
       ``G_k = V_3 Lambda_3^{1/2}`` from its top three eigenpairs, and each block
       ``Pi_hat_f G_k = c_fk R_f`` projected to the nearest matrix with orthonormal rows
       (which divides out ``|c_fk|``) gives Dai et al.'s rotations.
    4. *Joint fit of the exact triples* (this project's addition, :func:`_fit_triples`).
       The rotations are refined so that k column triples of the motion factor, not one,
       are scaled copies of the same ``R_f`` (:class:`_MotionFit`), for k = 1, 2, ... in
       turn, each fit continuing from the previous one (the first from step 3), with a
       multi-start search (random 3-dim subspaces of Q's top eigenvectors, seeded by
       ``seed``, and the rigid estimate) when that fit is not already exact. The fit works
       in every direction of W above the noise (at least 3K of them), and k grows only
       while the k-th triple fits *exactly*, i.e. with the misfit that the noise of W
       explains (or at rounding level without noise). Dai et al. stop at step 3, which
       has two weaknesses we measured: the trace-minimal Q is generally of rank above 3
       (1-12 degree errors without noise), and one triple fixes the rotations only to
       second order, so 0.01 % noise already gave 5-10 degree errors for K = 3, 4. Fitting
       all K triples regardless (the previous version) is right for exactly low-rank data
       but not for realistic deformations: a face's expressions are not K full xyz bases,
       only 2 triples of the synthetic faces are exact, and only in all 13 significant
       directions of W; forcing K triples into 3K directions pulled the rotations 4-23
       degrees away from the truth, even when started there.
    5. The sign of ``c_fk``, which the model cannot see, is resolved by assuming a dominant
       shape (:func:`_synchronise_signs`).

    Measured (tests/moju_core/test_rotations.py and the project's sequences): below 1e-4
    degrees without noise and 0.2-1.0 degrees with 1 % noise on exactly low-rank data for
    K = 2..4; below 0.01 degrees on the noise-free synthetic faces of 99 frames and about
    1.2 degrees on the 10-frame face1, where 10 frames leave the rotations partly
    undetermined.

    K = 1 is the rigid case and is delegated to :func:`rigid_rotations`. A K above what W
    supports (3K above its rank, or above the number of singular values that stand out of
    the noise by the rule of :func:`choose_n_bases`) is lowered with a ``RuntimeWarning``.
    When the relaxation is degenerate (Q of rank below 3, e.g. a camera that never tilts),
    a ``RuntimeWarning`` is issued and K - 1 bases are tried, down to the rigid method.
    When not even one triple fits within the noise (the deformation does not follow the
    low-rank model, e.g. a strongly bending sheet), the best single-triple fit is returned
    with a ``RuntimeWarning`` that the rotations may be inaccurate.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Row-centred measurements.
    n_bases : int
        Number of shape bases K >= 1; needs ``F >= ceil(5K(K+1)/4)`` and ``P >= 3K + 1``.
        It sets the rank of Dai et al.'s factorisation and the largest number of triples
        fitted. A K above what W supports is lowered with a ``RuntimeWarning``.
    seed : int, default=0
        Seed of the random starting points of the joint fit's search.

    Returns
    -------
    ndarray of shape (F, 2, 3), float64
        Rotations with orthonormal rows, up to one global rotation and reflection.

    Raises
    ------
    MeasurementError
        If W is malformed, zero, or too small for ``n_bases``.
    ValueError
        If ``n_bases`` is not a positive integer.
    """
    W = _check_measurements(W)
    _check_n_bases(n_bases, W.shape[0] // 2, W.shape[1])
    return _intersection_from_spectrum(W, spectrum(W), int(n_bases), seed)


# ----------------------------------------------------------------------------------------
# Entry point
# ----------------------------------------------------------------------------------------


def estimate_rotations(
    W: np.ndarray,
    method: RotationEstimator = "intersection",
    *,
    n_bases: int | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Per-frame camera rotations of an orthographic sequence.

    Parameters
    ----------
    W : ndarray of shape (2F, P)
        Measurements with row means removed; rows 2f and 2f + 1 are x and y of frame f.
        Any scale (the solver divides by the RMS first; nothing here depends on it).
    method : {"intersection", "rigid"}, default="intersection"
        ``"intersection"``: Dai, Li and He's prior-free method for deforming objects
        (:func:`intersection_rotations`). ``"rigid"``: Tomasi-Kanade
        (:func:`rigid_rotations`).
    n_bases : int or None, default=None
        Number of shape bases K for ``"intersection"``; ``None`` chooses it with
        :func:`choose_n_bases`. Ignored by ``"rigid"``.
    seed : int, default=0
        Seed of the random starting points of the intersection method's joint fit (the
        rigid method is deterministic). Different seeds give the same rotations
        unless the misfit has several minima of nearly equal depth.

    Returns
    -------
    ndarray of shape (F, 2, 3), float64
        Camera rotations ``R_f`` with orthonormal rows, defined up to one global rotation
        and reflection.

    Raises
    ------
    MeasurementError
        If W is malformed (odd rows, non-finite values, fewer than 3 frames), zero, or too
        small for the number of shape bases.
    ValueError
        If ``method`` is unknown or ``n_bases`` is not a positive integer.
    """
    if method not in ("intersection", "rigid"):
        raise ValueError(f"method must be 'intersection' or 'rigid', got {method!r}")
    W = _check_measurements(W)
    n_frames, n_points = W.shape[0] // 2, W.shape[1]
    if method == "rigid":
        _check_n_bases(1, n_frames, n_points)
        return _rigid_from_spectrum(spectrum(W))
    if n_bases is not None:
        _check_n_bases(n_bases, n_frames, n_points)
    # One spectrum serves both the choice of K and the factorisation.
    decomposition = spectrum(W)
    if n_bases is None:
        n_bases = _n_bases_from_spectrum(decomposition.singular, W.shape, 10)
        _check_n_bases(n_bases, n_frames, n_points)
    return _intersection_from_spectrum(W, decomposition, int(n_bases), seed)
