"""Singular values of the measurements: the spectrum, its numerical rank and its noise level.

The camera estimators (:mod:`moju_core.cameras`), the solver's noise estimate and the
smoothness choice (:mod:`moju_core.priors.smoothness`) and the low-rank completion
(:mod:`moju_core.completion.missing`) all read the singular values of a 2F x P matrix W. They come
from
the smaller Gram matrix, ``W W^T`` (2F x 2F) or ``W^T W`` (P x P), so that the cost in the
larger dimension is a single matrix product. Which singular values are signal is decided by
Gavish and Donoho's optimal hard threshold for white noise of unknown level; the energy of the
others gives the noise variance.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "RANK_FLOOR",
    "Spectrum",
    "noise_variance",
    "noise_variance_beyond",
    "significant_rank",
    "spectrum",
]

#: Singular values of W below this fraction of the largest are treated as exact zeros. The
#: Gram-matrix route computes s_i^2 with an absolute error of about eps * s_1^2, so singular
#: values are only resolved down to about sqrt(eps) * s_1 ~ 1.5e-8 * s_1; 1e-6 stays clear of
#: that floor while being far below any deformation that matters for the rotations.
RANK_FLOOR = 1e-6


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
    rank rules here and in :mod:`moju_core.cameras` never rely on them (see ``RANK_FLOOR``).

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
    """Number of singular values of W above the noise (step 1 of
    :func:`moju_core.cameras.bases.choose_n_bases`).

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
    threshold = max(_gavish_donoho_threshold(s, shape[0] / shape[1]), RANK_FLOOR * s[0])
    return int(np.count_nonzero(s > threshold))


def noise_variance_beyond(s: np.ndarray, shape: tuple[int, int], rank: int) -> float:
    """Variance of white noise in the entries of W, from its singular values beyond ``rank``.

    Noise of variance sigma^2 puts about ``sigma^2 (m - r)(M - r)`` of energy into the
    ``m - r`` trailing directions of an m x M matrix (m <= M) whose signal has rank r. Without
    noise the result is a rounding error (or, for a W that is only approximately of rank r,
    the energy of the neglected directions spread the same way).

    Parameters
    ----------
    s : ndarray of shape (min(shape),)
        Singular values of W, decreasing.
    shape : (int, int)
        Shape of W.
    rank : int
        Rank r of the signal: the singular values from the (r + 1)-th on are noise.

    Returns
    -------
    float
        sigma^2, in squared units of the entries of W (0 when ``rank >= min(shape)``).
    """
    m, M = min(shape), max(shape)
    if rank >= m:
        return 0.0
    return float(np.sum(s[rank:m] ** 2) / ((m - rank) * (M - rank)))


def noise_variance(singular_values: np.ndarray, shape: tuple[int, int]) -> float:
    """Variance of white noise in the entries of a matrix, from its singular values.

    The singular values above the Gavish-Donoho threshold are signal (the rule of
    :func:`moju_core.cameras.bases.choose_n_bases`); the energy of the others is spread as
    white noise would spread it (see :func:`noise_variance_beyond`).

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
    return noise_variance_beyond(singular_values, shape, significant_rank(singular_values, shape))


def project_tracks(tracks: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``U U^T W``: the tracks projected onto an orthonormal basis of the frame side.

    Parameters
    ----------
    tracks : ndarray of shape (F, 2, P)
    basis : ndarray of shape (2F, r)
        Orthonormal columns (the signal subspace of W).

    Returns
    -------
    ndarray of shape (F, 2, P)
        O(F P r).
    """
    n_frames, _, n_points = tracks.shape
    flat = tracks.reshape(2 * n_frames, n_points)
    return (basis @ (basis.T @ flat)).reshape(n_frames, 2, n_points)
