"""Proximal steps of the ADMM loop: singular value thresholding and the LRR coefficient step."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg

from moju_core.loop import leading_svd
from moju_core.loop.leading_svd import WarmStart

#: Shorter side of x from which a call given a warm start takes the truncated route: below it
#: the Gram route is cheaper (and the results of smaller problems stay those of the Gram route).
TRUNCATED_MIN_SIDE = 400
#: :func:`_leading_eigh`: the subset eigensolver runs while the expected pairs are at most
#: this fraction of the Gram matrix's side (its cost equals the full one's at about 12 pairs
#: for n = 99 and 14 for n = 123).
SUBSET_MAX_FRACTION = 0.125


def singular_value_threshold(
    x: np.ndarray,
    tau: float,
    out: np.ndarray | None = None,
    *,
    keep: int = 0,
    left: Callable[[np.ndarray], np.ndarray] | None = None,
    warm: WarmStart | None = None,
) -> tuple[np.ndarray, float]:
    """Proximal operator of ``tau ||.||_*``: ``U max(Sigma - tau, 0) V^T`` (Algorithm 1, 10-11).

    ``argmin_Y tau ||Y||_* + 0.5 ||Y - X||_F^2``. With ``keep = r > 0`` the r largest singular
    values are left as they are and only the others are shrunk: the proximal operator of the
    partial sum ``tau sum_{i > r} sigma_i(Y)`` (Oh et al., "Partial sum minimization of
    singular values in RPCA", ICCV 2013), which penalises all but the r dominant directions.

    Computed through the Gram matrix of the shorter side, so an (m, n) input costs
    ``O(m n min(m, n))``. For a wide X (like ``S#`` of shape (F, 3P) with F <= 3P), with
    ``X X^T = U L U^T`` the result is ``U_r diag(max(s - tau, 0) / s) U_r^T X`` over the r
    singular values above tau, so only an (F, F) eigenproblem and products with r rows are
    needed; a tall X (F > 3P: long sequences of few points) uses the (n, n) matrix ``X^T X``
    the same way from the right. Even for a square X (the LRR matrix Z, K x K) the symmetric
    eigenproblem costs half an SVD (0.05 s against 0.10 s at K = 600, one thread). The Gram
    route loses accuracy only on singular values below about ``sqrt(eps) * s_max``; those are
    shrunk to zero unless tau is below that level.

    Given a ``warm`` start, an input whose shorter side is at least ``TRUNCATED_MIN_SIDE``
    takes the truncated route instead (:func:`moju_core.loop.leading_svd.leading_triplets`): only
    the r values above tau are computed, by a subspace iteration on the row side started from
    the previous call's vectors, ``O(m n (r + 4))`` per sweep and a few sweeps when the input
    changed little (the ADMM loop's S# from one iteration to the next). Its result equals the
    Gram route's to about ``1e-11 s_max`` per returned triplet; where the iteration would need
    more than a quarter of the shorter side, or does not settle, the Gram route runs.

    Parameters
    ----------
    x : ndarray of shape (m, n)
    tau : float
        Threshold, >= 0.
    out : ndarray of shape (m, n), optional
        Where to write the result (must not share memory with x).
    keep : int, default 0
        Number of leading singular values left unshrunk (0: the plain nuclear norm).
    left : callable, optional
        A linear map applied to the result from the left, ``y <- left(y)``, given as a
        function of an (m, k) array: the temporal prior's filter
        (:class:`moju_core.priors.temporal_prior.FrameFilter`). It acts on the r surviving left
        singular directions only, so it costs what ``left`` costs on r columns.
    warm : WarmStart, optional
        The truncated route's state (:class:`moju_core.loop.leading_svd.WarmStart`), kept by the
        caller from one call to the next on inputs with the same number of rows; updated.
        None: always the Gram route.

    Returns
    -------
    y : ndarray of shape (m, n)
    nuclear_norm : float
        ``||y||_*`` (all singular values, the kept ones included).
    """
    route = None
    if warm is not None and min(x.shape) >= TRUNCATED_MIN_SIDE:
        route = leading_svd.leading_triplets(x, tau, keep, warm)
    if route is None:
        expected = None if warm is None else warm.surviving
        columns, rows, column_scale, nuclear = _gram_route(x, tau, keep, expected)
        if warm is not None:
            warm.surviving = columns.shape[1]
    else:
        # y = [U_r diag(shrunk / s)] [U_r^T x], as the wide Gram route.
        vectors, s, rows = route
        shrunk = np.clip(s - tau, 0.0, None)
        shrunk[:keep] = s[:keep]
        columns, column_scale, nuclear = vectors * (shrunk / s), s, float(shrunk.sum())
    if left is not None and columns.shape[1]:
        columns = left(columns)
        # y = (left(U_r) diag(shrunk)) V_r^T with V_r orthonormal: the nuclear norm of y is
        # that of the (m, r) factor.
        nuclear = float(np.linalg.svd(columns * column_scale, compute_uv=False).sum())
    return np.matmul(columns, rows, out=out), nuclear


def _gram_route(
    x: np.ndarray, tau: float, keep: int, expected: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The threshold's factors through the Gram matrix of the shorter side of x (m, n);
    ``expected`` is the number of values likely to survive (:func:`_leading_eigh`).

    Returns ``(columns, rows, column_scale, nuclear)``: the result is ``columns @ rows``,
    ``columns * column_scale`` is ``U_r diag(shrunk)`` (m, r) and ``nuclear`` the sum of the
    shrunk values.
    """
    m, n = x.shape
    wide = m <= n
    values, vectors = _leading_eigh(x @ x.T if wide else x.T @ x, tau, keep, expected)
    s = np.sqrt(np.clip(values, 0.0, None))
    shrunk = np.clip(s - tau, 0.0, None)
    if keep > 0:
        # eigh returns ascending eigenvalues: the r largest singular values are the last r.
        shrunk[-keep:] = s[-keep:]
    surviving = shrunk > 0
    # Only the r surviving directions are applied: O(r m n) instead of O(m n min(m, n)).
    kept = vectors[:, surviving]
    factors = shrunk[surviving] / s[surviving]
    nuclear = float(shrunk.sum())
    if wide:
        # y = [U_r diag(shrunk / s)] [U_r^T x]; the first factor times diag(s) is U_r diag(shrunk).
        return kept * factors, kept.T @ x, s[surviving], nuclear
    # y = [x V_r diag(shrunk / s)] V_r^T; the first factor is U_r diag(shrunk).
    return (x @ kept) * factors, kept.T, np.ones(len(factors)), nuclear


def _leading_eigh(
    gram: np.ndarray, tau: float, keep: int, expected: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The eigenpairs of a PSD Gram matrix (n, n) above ``tau^2``, and at least its ``keep``
    largest, in ascending order (all of them where that is cheaper).

    LAPACK's MRRR driver computes only the requested pairs after the tridiagonal reduction,
    but each pair costs about 0.06 of a full eigendecomposition at n = 99-123 (one thread,
    AMD EPYC: 0.43 of numpy's ``eigh`` for 2 pairs, 0.88 for 10, 1.44 for 20 at n = 99; 0.32,
    0.50, 0.71 at n = 200). So the full one (divide and conquer) runs when ``expected``, the
    count of the caller's previous call (the loop's S# changes little between iterations),
    is above :data:`SUBSET_MAX_FRACTION` of n.
    """
    n = gram.shape[0]
    if tau <= 0.0 or n == 0 or (expected is not None and expected > SUBSET_MAX_FRACTION * n):
        return np.linalg.eigh(gram)
    values, vectors = scipy.linalg.eigh(
        gram, subset_by_value=(tau * tau, np.inf), driver="evr", check_finite=False
    )
    if len(values) < min(keep, n):
        values, vectors = scipy.linalg.eigh(
            gram, subset_by_index=(n - min(keep, n), n - 1), driver="evr", check_finite=False
        )
    return values, vectors


def top_singular_value(x: np.ndarray) -> float:
    """Largest singular value of x (m, n).

    Through the Gram matrix of its shorter side, ``O(m n min(m, n))``; from a shorter side of
    ``TRUNCATED_MIN_SIDE`` on by a few sweeps of a small block
    (:func:`moju_core.loop.leading_svd.leading_triplets`), ``O(m n)``.
    """
    if min(x.shape) >= TRUNCATED_MIN_SIDE:
        route = leading_svd.leading_triplets(x, np.inf, 1, WarmStart())
        if route is not None:
            return float(route[1][0])
    gram = x @ x.T if x.shape[0] <= x.shape[1] else x.T @ x
    return float(np.sqrt(max(np.linalg.eigvalsh(gram)[-1], 0.0)))


def kernel_eigh(gamma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigendecomposition ``Gamma = V diag(lambda) V^T`` of a symmetric PSD kernel (K x K).

    The C-step's system matrix ``2 beta1 Gamma + rho I`` changes with rho every iteration,
    but Gamma only when the grouping steps run; with this decomposition every C-step is two
    K x K products instead of a Cholesky factorisation and solve.

    Returns
    -------
    values : ndarray of shape (K,)
        Eigenvalues, clipped at 0 (rounding can make the smallest slightly negative).
    vectors : ndarray of shape (K, K)
        Orthonormal eigenvectors.
    """
    values, vectors = np.linalg.eigh(gamma)
    return np.clip(values, 0.0, None), vectors


def coefficient_step(
    kernel: tuple[np.ndarray, np.ndarray],
    z: np.ndarray,
    multiplier: np.ndarray,
    beta1: float,
    rho: float,
) -> np.ndarray:
    """C-step of LRR on the Grassmann manifold (Algorithm 1, step 7).

    Minimises ``beta1 ||chi - chi C||^2 + <L2, C - Z> + rho/2 ||C - Z||_F^2`` where, through the
    kernel, ``||chi - chi C||^2 = tr(Gamma) - 2 tr(Gamma C) + tr(C^T Gamma C)``. Setting the
    gradient to zero gives the linear system ``(2 beta1 Gamma + rho I) C = 2 beta1 Gamma +
    rho Z - L2``; with ``Gamma = V diag(lambda) V^T`` its solution is
    ``C = V [diag(2 beta1 lambda / d) V^T + diag(1 / d) V^T (rho Z - L2)]`` with
    ``d = 2 beta1 lambda + rho > 0``.

    Parameters
    ----------
    kernel : (ndarray of shape (K,), ndarray of shape (K, K))
        Eigendecomposition of the PSD kernel Gamma of the Grassmann points
        (:func:`kernel_eigh`).
    z : ndarray of shape (K, K)
        Auxiliary copy of C (the nuclear-norm variable).
    multiplier : ndarray of shape (K, K)
        Lagrange multiplier L2 of ``C = Z``.
    beta1, rho : float
        LRR weight and current penalty.

    Returns
    -------
    ndarray of shape (K, K)
    """
    values, vectors = kernel
    weighted = 2.0 * beta1 * values
    denominator = weighted + rho
    inner = vectors.T @ (rho * z - multiplier)
    inner /= denominator[:, None]
    inner += (weighted / denominator)[:, None] * vectors.T
    return vectors @ inner
