"""The jump to the low-dimensional Grassmann manifold (paper Eqs. 2-7, ``f_h``).

A map ``Delta`` (3F x d) sends each high-dimensional Grassmann point ``Phi_i`` (3F x p) to
``Delta^T Phi_i = Theta_i U_i`` (thin QR), a point ``Theta_i`` of G(p, d). With
``Omega_i = Phi_i U_i^{-1}``, ``Theta_i = Delta^T Omega_i`` (Eq. 3). Delta is chosen so that
neighbouring groups stay close on the low-dimensional manifold (Eq. 7)::

    minimise  E(Delta) = sum_ij w_ij 0.5 ||Delta^T Lambda_ij Delta||_F^2,
              Lambda_ij = Omega_i Omega_i^T - Omega_j Omega_j^T
    subject to trace(Delta^T D Delta) = 1,   D = sum_i lambda_ii Omega_i Omega_i^T,
               lambda_ii = sum_j w_ij.

E is quartic in Delta. Fixing ``M = Delta Delta^T`` inside one factor (iteratively reweighted)
gives the quadratic form ``A = sum_ij L_ij A_i A_j^T`` with ``A_i = Omega_i (Omega_i^T Delta)``
and ``L`` the graph Laplacian of ``w``, so each round is the generalized symmetric eigenproblem
``A x = mu D x`` for the d smallest eigenpairs. ``A`` is accumulated as
``sum_i A_i (sum_j L_ij A_j)^T``: K products of (3F x d) blocks, never K^2 products of 3F x 3F
matrices.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg


def initial_map(n: int, d: int, rng: np.random.Generator) -> np.ndarray:
    """``Delta = [I_d; small random]`` of shape (n, d), as in Algorithm 1's initialisation."""
    delta = np.zeros((n, d))
    delta[:d] = np.eye(d)
    delta[d:] = 1e-2 * rng.standard_normal((n - d, d))
    return delta


def low_dimensional_points(delta: np.ndarray, bases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Theta_i`` and ``Omega_i`` of every group (paper Eqs. 2-3).

    Parameters
    ----------
    delta : ndarray of shape (n, d)
    bases : ndarray of shape (K, n, p)
        High-dimensional Grassmann points ``Phi_i``.

    Returns
    -------
    thetas : ndarray of shape (K, d, p)
        Orthonormal columns: points of G(p, d).
    omegas : ndarray of shape (K, n, p)
        ``Phi_i U_i^{-1}``, so that ``Delta^T Omega_i = Theta_i``.
    """
    reduced = delta.T @ bases  # (K, d, p)
    thetas, upper = np.linalg.qr(reduced)
    # A group whose subspace Delta nearly annihilates has a near-singular U_i; bound its
    # diagonal away from zero (keeping the sign) so Omega_i stays finite.
    diag = np.einsum("kii->ki", upper)
    floor = 1e-8 * max(1.0, float(np.abs(diag).max()))
    small = np.abs(diag) < floor
    if small.any():
        sign = np.where(diag >= 0, 1.0, -1.0)
        idx = np.nonzero(small)
        upper[idx[0], idx[1], idx[1]] = sign[small] * floor
    # Omega_i = Phi_i U_i^{-1}  <=>  U_i^T Omega_i^T = Phi_i^T
    omegas = np.linalg.solve(np.swapaxes(upper, 1, 2), np.swapaxes(bases, 1, 2))
    return thetas, np.swapaxes(omegas, 1, 2)


def jump_objective(delta: np.ndarray, omegas: np.ndarray, weights: np.ndarray) -> float:
    """Value of Eq. 7's objective ``E(Delta)`` for fixed ``Omega_i``.

    Parameters
    ----------
    delta : ndarray of shape (n, d)
    omegas : ndarray of shape (K, n, p)
    weights : ndarray of shape (K, K)
        Symmetric similarity graph ``w``.

    Returns
    -------
    float
    """
    reduced = np.einsum("nd,knp->kdp", delta, omegas)
    embedded = np.einsum("kdp,kep->kde", reduced, reduced).reshape(len(omegas), -1)
    sq = np.einsum("kx,kx->k", embedded, embedded)
    dist = sq[:, None] + sq[None, :] - 2.0 * embedded @ embedded.T
    return float(0.5 * np.sum(weights * np.clip(dist, 0.0, None)))


def update_map(delta: np.ndarray, omegas: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """One reweighted round of Eq. 7: the d smallest generalized eigenvectors of ``(A, D)``.

    Parameters
    ----------
    delta : ndarray of shape (n, d)
        Current map; fixes ``M = Delta Delta^T`` inside the quartic objective.
    omegas : ndarray of shape (K, n, p)
    weights : ndarray of shape (K, K)
        Symmetric, non-negative similarity graph with zero diagonal.

    Returns
    -------
    ndarray of shape (n, d)
        New map with ``trace(Delta^T D Delta) = 1``.
    """
    n, d = delta.shape
    n_groups = len(omegas)
    degrees = weights.sum(axis=1)
    laplacian = np.diag(degrees) - weights
    weighted = omegas * np.sqrt(degrees)[:, None, None]
    flat = weighted.transpose(1, 0, 2).reshape(n, -1)  # D = flat flat^T
    # A and D map into the span of the Omega_i (K p directions): when that is smaller than
    # R^n (few groups, long sequences) the eigenproblem is solved in an orthonormal basis of
    # it, which is exact and costs O(n (K p)^2) instead of O(n^3); outside the span D = 0 and
    # the problem has no finite eigenvalues.
    span = _span_basis(flat, d) if flat.shape[1] < n else None
    if span is not None:
        omegas = span.T @ omegas  # (K, r, p)
        delta = span.T @ delta
        flat = span.T @ flat
    blocks = omegas @ (np.swapaxes(omegas, 1, 2) @ delta)  # A_i = Omega_i Omega_i^T Delta
    size = blocks.shape[1]
    mixed = (laplacian @ blocks.reshape(n_groups, size * d)).reshape(n_groups, size, d)
    # sum_i A_i mixed_i^T as one (n, K d) x (K d, n) product
    a = blocks.transpose(1, 0, 2).reshape(size, -1) @ mixed.transpose(1, 0, 2).reshape(size, -1).T
    a = 0.5 * (a + a.T)
    b = flat @ flat.T
    # D is PSD but rank-deficient when the groups span less than R^n; a relative ridge makes
    # it definite without changing the well-determined directions.
    b += (1e-9 * np.trace(b) / size + 1e-300) * np.eye(size)
    _, vectors = scipy.linalg.eigh(a, b, subset_by_index=[0, d - 1])
    if span is not None:
        vectors = span @ vectors
    # eigh normalises x^T D x = 1 per column; the constraint asks for a total trace of 1.
    return vectors / np.sqrt(d)


def _span_basis(flat: np.ndarray, d: int) -> np.ndarray | None:
    """Orthonormal basis (n, r) of the column span of ``flat``, or None if r < d."""
    left, singular, _ = np.linalg.svd(flat, full_matrices=False)
    rank = int(np.count_nonzero(singular > 1e-10 * singular[0])) if singular.size else 0
    return left[:, :rank] if rank >= d else None


def jump(
    delta: np.ndarray, bases: np.ndarray, weights: np.ndarray, rounds: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Solve Eq. 7 by alternating Omega updates and reweighted eigen-steps; return Delta, Theta.

    Parameters
    ----------
    delta : ndarray of shape (n, d)
        Warm start.
    bases : ndarray of shape (K, n, p)
    weights : ndarray of shape (K, K)
    rounds : int
        Reweighting rounds (the docs' 1-3).

    Returns
    -------
    delta : ndarray of shape (n, d)
    thetas : ndarray of shape (K, d, p)
    """
    for _ in range(rounds):
        _, omegas = low_dimensional_points(delta, bases)
        delta = update_map(delta, omegas, weights)
    thetas, _ = low_dimensional_points(delta, bases)
    return delta, thetas
