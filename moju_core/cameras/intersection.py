"""Camera rotations of a deforming object by Dai, Li and He's prior-free method.

Dai, Li and He, "A simple prior-free method for non-rigid structure-from-motion
factorization" (CVPR 2012 / IJCV 2014), followed by a joint fit. The measurements are
factorised at rank 3K, ``W ~ Pi_hat B_hat``; the unknown corrective column triple ``G_k``
(3K x 3) enters only through ``Q = G_k G_k^T``, on which every frame imposes two linear
equations (:func:`moju_core.cameras.rigid.metric_constraints`). ``Q`` is the positive
semidefinite matrix of smallest trace in the (numerical) null space of those equations
(:func:`_min_trace_psd`); its top three eigenpairs give ``G_k`` and every frame block
``Pi_hat_f G_k = c_fk R_f`` gives a rotation (Dai et al.'s estimate). One triple fixes the
rotations only to second order, so they are then refined so that several triples of the
motion factor are scaled copies of the same rotations
(:func:`moju_core.cameras.triples.fit_triples`). A degenerate relaxation (Q of rank below 3)
lowers K step by step, down to the rigid method; data in which not even one triple fits get
a warning. The sign of every frame, which the model cannot see, is resolved by assuming a
dominant shape (:func:`_synchronise_signs`).

Everything works on the left singular vectors of W (:func:`moju_core.spectrum.spectrum`),
so the cost in the number of points P is a single matrix product. Rotations are defined up to
one global rotation and a reflection, which is inherent to orthographic structure from
motion.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from moju_core.cameras.bases import check_measurements, check_n_bases
from moju_core.cameras.refinement import project_to_stiefel
from moju_core.cameras.rigid import metric_constraints, rigid_from_spectrum
from moju_core.cameras.symmetric import project_psd, smat, svec
from moju_core.cameras.triples import fit_frames, fit_triples, rotations_from_triples
from moju_core.errors import MeasurementError
from moju_core.spectrum import RANK_FLOOR, Spectrum, significant_rank, spectrum

__all__ = ["intersection_estimate", "intersection_rotations"]

# Dai's trace relaxation only provides starting points (the joint fit then converges to
# rounding level), so a moderate ADMM tolerance and iteration budget are enough.
_ADMM_TOL = 1e-6
_ADMM_MAX_ITER = 2000
# Largest number of directions of W the joint fit works in (H is 3n x 3n): a cost bound.
_MAX_FIT_RANK = 30
# Starts of the joint fit's multi-start search: random 3-dim subspaces of the top
# _SUBSPACE_WIDTH eigenvectors of the relaxation's Q (besides its top-3 factor, the previous
# number of triples' fit and the rigid estimate): a search budget against wrong minima.
_SUBSPACE_STARTS = 6
_SUBSPACE_WIDTH = 6
# Q from the convex relaxation must have a clear third eigenvalue: lambda_3 >= this *
# lambda_1. Below it the top-3 factor is not a rotation basis and the estimate is rejected.
_DEGENERATE_EIGEN_RATIO = 1e-6


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
    identity = svec(np.eye(n))

    def project_affine(v: np.ndarray) -> np.ndarray:
        y = basis.T @ v
        y += (1.0 - g @ y) / g_norm2 * g
        return basis @ y

    # Start from the affine point nearest to the origin; its PSD projection seeds Z.
    x = project_affine(np.zeros_like(normal))
    z = svec(project_psd(smat(x, n)))
    y = np.zeros_like(z)
    rho = 1.0
    for _ in range(max_iter):
        x = project_affine(z - y - identity / rho)
        z_old = z
        z = svec(project_psd(smat(x + y, n)))
        y += x - z
        primal = np.linalg.norm(x - z)
        dual = rho * np.linalg.norm(z - z_old)
        if primal <= tol * max(np.linalg.norm(x), np.linalg.norm(z)) and dual <= tol * max(
            rho * np.linalg.norm(y), 1.0
        ):
            return smat(z, n), True
        if primal > 10.0 * dual:
            rho *= 2.0
            y /= 2.0
        elif dual > 10.0 * primal:
            rho /= 2.0
            y *= 2.0
    return smat(z, n), False


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
    basis = _null_space(metric_constraints(Pi), 2 * k**2 - k)
    # Normalise with all frames together, tr(Pi Q Pi^T) = 1, so that no single frame (the
    # first frame's block = I of the paper) has to be well conditioned.
    Q, _ = _min_trace_psd(basis, svec(Pi.T @ Pi), n)
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
    exact_rank = int(np.count_nonzero(s > RANK_FLOOR * s[0]))
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
        starts.append(rigid_from_spectrum(spectrum))
        frames = fit_frames(W.shape[0] // 2)
        rows = (2 * frames[:, None] + np.arange(2)).reshape(-1)
        rotations, n_exact, excess, fit, weights = fit_triples(
            W.shape, U[rows, :n], s, n_bases, [start[frames] for start in starts]
        )
        if len(frames) < W.shape[0] // 2:
            rotations = rotations_from_triples(fit.triples(rotations), U[:, :n] * weights)
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


def _intersection_from_spectrum(
    W: np.ndarray, spectrum: Spectrum, n_bases: int, seed: int
) -> tuple[np.ndarray, bool]:
    """Body of :func:`intersection_estimate` for a validated W and its spectrum."""
    s = spectrum.singular
    if s[0] <= 0.0:
        raise MeasurementError("W is zero after centring: the points do not move in the image")
    # A basis beyond the exact rank of W (a rank-deficient W, e.g. a K too large for
    # noise-free data) has only rounding errors in its columns of Pi_hat: no triple there is a
    # scaled rotation.
    exact_rank = int(np.count_nonzero(s > RANK_FLOOR * s[0]))
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
            return rotations, False
        fallback = f"n_bases={k - 1}" if k > 2 else "rigid (Tomasi-Kanade) rotations"
        warnings.warn(
            f"intersection rotations with n_bases={k} failed: {failure}; trying {fallback}",
            RuntimeWarning,
            stacklevel=3,
        )
    return rigid_from_spectrum(spectrum), True


def intersection_estimate(
    W: np.ndarray, n_bases: int, *, seed: int = 0, decomposition: Spectrum | None = None
) -> tuple[np.ndarray, bool]:
    """:func:`intersection_rotations`, and whether they are the rigid (Tomasi-Kanade) rotations.

    The method falls back to the rigid rotations when W supports one shape basis only or
    when the relaxation stays degenerate down to two bases; the camera step then reports
    them as ``"rigid"``.

    Returns
    -------
    rotations : ndarray of shape (F, 2, 3), float64
    rigid : bool
        True when the rotations are :func:`moju_core.cameras.rigid.rigid_rotations` of W.
    """
    W = check_measurements(W)
    check_n_bases(n_bases, W.shape[0] // 2, W.shape[1])
    if decomposition is None:
        decomposition = spectrum(W)
    return _intersection_from_spectrum(W, decomposition, int(n_bases), seed)


def intersection_rotations(
    W: np.ndarray, n_bases: int, *, seed: int = 0, decomposition: Spectrum | None = None
) -> np.ndarray:
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
    4. *Joint fit of the exact triples* (this project's addition,
       :func:`moju_core.cameras.triples.fit_triples`).
       The rotations are refined so that k column triples of the motion factor, not one,
       are scaled copies of the same ``R_f`` (:class:`moju_core.cameras.triples.MotionFit`),
       for k = 1, 2, ... in turn, each fit continuing from the previous one (the first from
       step 3), with a multi-start search (random 3-dim subspaces of Q's top eigenvectors,
       seeded by ``seed``, and the rigid estimate) when that fit is not already exact. The fit works
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

    Measured (tests/moju_core/cameras/test_intersection.py and the project's sequences): below 1e-4
    degrees without noise and 0.2-1.0 degrees with 1 % noise on exactly low-rank data for
    K = 2..4; below 0.01 degrees on the noise-free synthetic faces of 99 frames and about
    1.2 degrees on the 10-frame face1, where 10 frames leave the rotations partly
    undetermined.

    K = 1 is the rigid case and is delegated to :func:`moju_core.cameras.rigid.rigid_rotations`.
    A K above what W supports (3K above its rank, or above the number of singular values
    that stand out of the noise by the rule of :func:`moju_core.cameras.bases.choose_n_bases`)
    is lowered with a ``RuntimeWarning``.
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
    decomposition : Spectrum, optional
        ``spectrum(W)``, if the caller already has it.

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
    return intersection_estimate(W, n_bases, seed=seed, decomposition=decomposition)[0]
