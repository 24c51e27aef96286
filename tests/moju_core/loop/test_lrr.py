"""Singular value thresholding and the LRR coefficient step."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core.loop.leading_svd import WarmStart
from moju_core.loop.lrr import coefficient_step, kernel_eigh, singular_value_threshold


def _prox_objective(y, x, tau):
    return tau * np.linalg.svd(y, compute_uv=False).sum() + 0.5 * np.linalg.norm(y - x) ** 2


@pytest.mark.parametrize("shape", [(6, 40), (15, 15), (40, 6)])  # wide, square and tall
def test_svt_matches_shrunk_svd(shape):
    rng = np.random.default_rng(0)
    x = rng.standard_normal(shape)
    tau = 1.5
    y, nuclear = singular_value_threshold(x, tau)
    u, s, vt = np.linalg.svd(x, full_matrices=False)
    shrunk = np.clip(s - tau, 0, None)
    assert_allclose(y, (u * shrunk) @ vt, atol=1e-10)
    assert nuclear == pytest.approx(shrunk.sum(), rel=1e-10)


@pytest.mark.parametrize("shape", [(5, 30), (12, 12)])
def test_svt_is_the_proximal_operator_of_the_nuclear_norm(shape):
    rng = np.random.default_rng(1)
    x = rng.standard_normal(shape)
    tau = 0.8
    y, _ = singular_value_threshold(x, tau)
    best = _prox_objective(y, x, tau)
    for _ in range(200):
        perturbed = y + 1e-2 * rng.standard_normal(shape)
        assert _prox_objective(perturbed, x, tau) >= best - 1e-12
    # Optimality: (x - y) / tau is a subgradient of the nuclear norm at y (spectral norm <= 1).
    assert np.linalg.norm((x - y) / tau, 2) <= 1 + 1e-9


def test_svt_with_zero_threshold_is_identity_and_large_threshold_is_zero():
    x = np.random.default_rng(2).standard_normal((4, 25))
    assert_allclose(singular_value_threshold(x, 0.0)[0], x, atol=1e-10)
    assert_allclose(singular_value_threshold(x, 1e6)[0], 0.0)


def test_coefficient_step_satisfies_its_optimality_condition():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((8, 5))
    gamma = a @ a.T  # a PSD kernel, rank deficient on purpose
    z = rng.standard_normal((8, 8))
    multiplier = rng.standard_normal((8, 8))
    beta1, rho = 0.7, 0.3
    c = coefficient_step(kernel_eigh(gamma), z, multiplier, beta1, rho)
    # Gradient of beta1 (tr G - 2 tr(G C) + tr(C^T G C)) + <L2, C - Z> + rho/2 ||C - Z||^2.
    gradient = beta1 * (-2 * gamma + 2 * gamma @ c) + multiplier + rho * (c - z)
    assert_allclose(gradient, 0.0, atol=1e-10)


def test_coefficient_step_minimises_the_augmented_objective():
    rng = np.random.default_rng(4)
    a = rng.standard_normal((6, 6))
    gamma = a @ a.T
    z, multiplier = rng.standard_normal((2, 6, 6))
    beta1, rho = 2.0, 0.5

    def objective(c):
        lrr = np.trace(gamma) - 2 * np.trace(gamma @ c) + np.trace(c.T @ gamma @ c)
        return beta1 * lrr + np.sum(multiplier * (c - z)) + rho / 2 * np.linalg.norm(c - z) ** 2

    c = coefficient_step(kernel_eigh(gamma), z, multiplier, beta1, rho)
    for _ in range(100):
        assert objective(c + 1e-3 * rng.standard_normal(c.shape)) > objective(c)


@pytest.mark.parametrize("keep", [1, 2])
def test_svt_keeping_the_top_values_is_the_prox_of_the_partial_sum(keep):
    rng = np.random.default_rng(5)
    x = rng.standard_normal((6, 30))
    tau = 1.2
    y, nuclear = singular_value_threshold(x, tau, keep=keep)
    u, s, vt = np.linalg.svd(x, full_matrices=False)
    expected = np.concatenate([s[:keep], np.clip(s[keep:] - tau, 0, None)])
    assert_allclose(y, (u * expected) @ vt, atol=1e-10)
    assert nuclear == pytest.approx(expected.sum(), rel=1e-10)

    def objective(candidate):
        values = np.linalg.svd(candidate, compute_uv=False)
        return tau * values[keep:].sum() + 0.5 * np.linalg.norm(candidate - x) ** 2

    best = objective(y)
    for _ in range(200):
        assert objective(y + 1e-2 * rng.standard_normal(x.shape)) >= best - 1e-12


@pytest.mark.parametrize("shape", [(7, 40), (40, 7)])
def test_svt_with_a_left_filter_filters_the_thresholded_result(shape):
    rng = np.random.default_rng(6)
    x = rng.standard_normal(shape)
    left = rng.standard_normal((shape[0], shape[0]))
    left = left @ left.T / shape[0]  # any matrix; the temporal prior's filter is symmetric
    y, nuclear = singular_value_threshold(x, 1.1, keep=1, left=lambda columns: left @ columns)
    plain, _ = singular_value_threshold(x, 1.1, keep=1)
    assert_allclose(y, left @ plain, atol=1e-10)
    assert nuclear == pytest.approx(np.linalg.svd(y, compute_uv=False).sum(), rel=1e-10)


def test_svt_of_a_tall_matrix_matches_the_wide_route():
    rng = np.random.default_rng(8)
    x = rng.standard_normal((60, 15))  # F > 3P: the Gram matrix of the short side
    tall, tall_norm = singular_value_threshold(x, 0.9, keep=1)
    wide, wide_norm = singular_value_threshold(np.ascontiguousarray(x.T), 0.9, keep=1)
    assert_allclose(tall, wide.T, atol=1e-10)
    assert tall_norm == pytest.approx(wide_norm, rel=1e-12)


def test_svt_with_a_left_filter_and_nothing_surviving_is_zero():
    x = np.random.default_rng(9).standard_normal((6, 20))
    y, nuclear = singular_value_threshold(x, 1e6, left=lambda columns: 2.0 * columns)
    assert_allclose(y, 0.0)
    assert nuclear == 0.0


@pytest.mark.parametrize(("shape", "keep"), [((40, 90), 0), ((90, 40), 3)])
def test_svt_gives_the_same_result_whichever_eigensolver_the_expected_count_picks(shape, keep):
    rng = np.random.default_rng(4)
    x = rng.standard_normal(shape) * np.logspace(0, -2, shape[1])
    tau = float(np.median(np.linalg.svd(x, compute_uv=False)))
    results = []
    for expected in (0, min(shape)):  # the subset route, then the full eigendecomposition
        warm = WarmStart()
        warm.surviving = expected
        results.append(singular_value_threshold(x, tau, keep=keep, warm=warm))
        # The call records its own count for the next one.
        assert warm.surviving == np.linalg.matrix_rank(results[-1][0])
    assert_allclose(results[0][0], results[1][0], atol=1e-10)
    assert results[0][1] == pytest.approx(results[1][1], rel=1e-12)
