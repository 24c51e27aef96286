"""Symmetric matrices as vectors, and the projection onto the positive semidefinite cone.

The metric constraints of the camera estimators act linearly on a symmetric corrective
matrix ``Q``; :func:`svec` writes ``Q`` as a vector in which the Euclidean inner product is
the Frobenius one, so that least-squares solutions and projections in that vector space are
those of the matrices.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["project_psd", "smat", "svec", "svec_indices"]


def svec_indices(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Upper-triangle indices of an n x n matrix and the svec weights (1 or sqrt(2))."""
    rows, cols = np.triu_indices(n)
    weights = np.where(rows == cols, 1.0, math.sqrt(2.0))
    return rows, cols, weights


def svec(M: np.ndarray) -> np.ndarray:
    """Isometric vectorisation of symmetric matrices: (..., n, n) -> (..., n(n+1)/2).

    Off-diagonal entries are weighted by sqrt(2) so that ``svec(A) . svec(B) = <A, B>_F``;
    projections in svec coordinates are then Frobenius projections of matrices.
    """
    rows, cols, weights = svec_indices(M.shape[-1])
    return M[..., rows, cols] * weights


def smat(v: np.ndarray, n: int) -> np.ndarray:
    """Inverse of :func:`svec` for one vector: (n(n+1)/2,) -> symmetric (n, n)."""
    rows, cols, weights = svec_indices(n)
    M = np.zeros((n, n))
    M[rows, cols] = v / weights
    M[cols, rows] = v / weights
    return M


def project_psd(M: np.ndarray) -> np.ndarray:
    """Frobenius projection of a symmetric matrix onto the PSD cone (eigenvalue clipping)."""
    eigenvalues, eigenvectors = np.linalg.eigh(M)
    return (eigenvectors * np.clip(eigenvalues, 0.0, None)) @ eigenvectors.T
