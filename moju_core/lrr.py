"""Proximal steps of the ADMM loop: singular value thresholding and the LRR coefficient step."""

from __future__ import annotations

import numpy as np
import scipy.linalg


def singular_value_threshold(
    x: np.ndarray, tau: float, out: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """Proximal operator of ``tau ||.||_*``: ``U max(Sigma - tau, 0) V^T`` (Algorithm 1, 10-11).

    ``argmin_Y tau ||Y||_* + 0.5 ||Y - X||_F^2``. Wide matrices (rows much fewer than columns,
    like ``S#`` of shape (F, 3P)) go through the Gram matrix ``X X^T``: with ``X X^T = U L U^T``
    the result is ``U_r diag(max(s - tau, 0) / s) U_r^T X`` over the r singular values above
    tau, so only an (F, F) eigenproblem and products with r rows are needed. The Gram route
    loses accuracy only on singular values below about ``sqrt(eps) * s_max``; those are shrunk
    to zero unless tau is below that level.

    Parameters
    ----------
    x : ndarray of shape (m, n)
    tau : float
        Threshold, >= 0.
    out : ndarray of shape (m, n), optional
        Where to write the result (must not share memory with x).

    Returns
    -------
    y : ndarray of shape (m, n)
    nuclear_norm : float
        ``||y||_*``.
    """
    m, n = x.shape
    if 4 * m <= n:
        gram = x @ x.T
        values, vectors = np.linalg.eigh(gram)
        s = np.sqrt(np.clip(values, 0.0, None))
        shrunk = np.clip(s - tau, 0.0, None)
        keep = shrunk > 0
        # Only the r surviving directions are applied: O(r m n) instead of O(m^2 n).
        kept = vectors[:, keep]
        y = np.matmul(kept * (shrunk[keep] / s[keep]), kept.T @ x, out=out)
        return y, float(shrunk.sum())
    u, s, vt = np.linalg.svd(x, full_matrices=False)
    shrunk = np.clip(s - tau, 0.0, None)
    keep = shrunk > 0
    y = np.matmul(u[:, keep] * shrunk[keep], vt[keep], out=out)
    return y, float(shrunk.sum())


def coefficient_step(
    gamma: np.ndarray, z: np.ndarray, multiplier: np.ndarray, beta1: float, rho: float
) -> np.ndarray:
    """C-step of LRR on the Grassmann manifold (Algorithm 1, step 7).

    Minimises ``beta1 ||chi - chi C||^2 + <L2, C - Z> + rho/2 ||C - Z||_F^2`` where, through the
    kernel, ``||chi - chi C||^2 = tr(Gamma) - 2 tr(Gamma C) + tr(C^T Gamma C)``. Setting the
    gradient to zero gives the linear system ``(2 beta1 Gamma + rho I) C = 2 beta1 Gamma +
    rho Z - L2``, solved by Cholesky (the matrix is symmetric positive definite for rho > 0).

    Parameters
    ----------
    gamma : ndarray of shape (K, K)
        PSD kernel of the Grassmann points.
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
    k = gamma.shape[0]
    lhs = 2.0 * beta1 * gamma + rho * np.eye(k)
    rhs = 2.0 * beta1 * gamma + rho * z - multiplier
    return scipy.linalg.cho_solve(scipy.linalg.cho_factor(lhs), rhs)
