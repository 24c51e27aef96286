"""Singular values through the smaller Gram matrix, the numerical rank and the noise level."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core.spectrum import noise_variance, project_tracks, significant_rank, spectrum


def _low_rank(n_rows: int, n_columns: int, rank: int, seed: int = 0) -> np.ndarray:
    """A random matrix of the given rank with entries of mean square 1."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n_rows, rank)) @ rng.standard_normal((rank, n_columns))
    return M / np.sqrt(np.mean(M**2))


def test_both_gram_routes_give_the_singular_values():
    # 2F <= P uses W W^T, P < 2F uses W^T W; both resolve the singular values of W down to
    # about sqrt(eps) s_1.
    W = _low_rank(120, 100, 6)
    for matrix in (W, W[:80], W[:, :60]):
        s = np.linalg.svd(matrix, compute_uv=False)
        decomposition = spectrum(matrix)
        assert_allclose(decomposition.singular, s, rtol=1e-8, atol=1e-7 * s[0])
        assert (decomposition.gram is not None) == (matrix.shape[0] <= matrix.shape[1])


@pytest.mark.parametrize("sigma", [0.0, 1e-3, 1e-2])
def test_rank_and_noise_of_a_low_rank_matrix_with_white_noise(sigma):
    W = _low_rank(120, 400, 9, seed=1)
    W += sigma * np.random.default_rng(2).standard_normal(W.shape)
    s = spectrum(W).singular
    assert significant_rank(s, W.shape) == 9
    if sigma == 0.0:
        # Rounding of the Gram route only (entries of mean square 1).
        assert noise_variance(s, W.shape) < 1e-12
    else:
        assert noise_variance(s, W.shape) == pytest.approx(sigma**2, rel=0.1)


def test_project_tracks_is_the_orthogonal_projection():
    rng = np.random.default_rng(0)
    tracks = rng.normal(size=(6, 2, 40))
    basis, _ = np.linalg.qr(rng.normal(size=(12, 3)))
    once = project_tracks(tracks, basis)
    np.testing.assert_allclose(project_tracks(once, basis), once, atol=1e-12)
    residual = (tracks - once).reshape(12, 40)
    np.testing.assert_allclose(basis.T @ residual, 0.0, atol=1e-12)
