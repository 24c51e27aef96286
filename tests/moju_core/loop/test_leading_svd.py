"""The truncated, warm-started singular value threshold (moju_core.loop.leading_svd) against the
exact one."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core import SolverParams, reconstruct
from moju_core.datasets import make_sequence
from moju_core.loop import leading_svd, lrr
from moju_core.priors.temporal_prior import smoothing_filter, temporal_prior

#: Shapes with a shorter side of at least lrr.TRUNCATED_MIN_SIDE: wide (S# of F <= 3P) and tall.
SHAPES = [(420, 900), (900, 420)]


def _low_rank_plus_noise(shape, rank=12, noise=1e-3, seed=0):
    """A matrix with ``rank`` values from 100 down to 0.1 over a noise floor near
    ``noise * sqrt(max(shape))``."""
    rng = np.random.default_rng(seed)
    m, n = shape
    values = 100.0 * 10.0 ** -np.linspace(0.0, 3.0, rank)
    left = np.linalg.qr(rng.standard_normal((m, rank)))[0]
    right = np.linalg.qr(rng.standard_normal((n, rank)))[0]
    return (left * values) @ right.T + noise * rng.standard_normal(shape)


def _exact(x, tau, keep=0, left=None):
    """The threshold from a full SVD: ``left(U) diag(shrunk) V^T``."""
    u, s, vt = np.linalg.svd(x, full_matrices=False)
    shrunk = np.concatenate([s[:keep], np.clip(s[keep:] - tau, 0.0, None)])
    columns = u * shrunk
    if left is not None:
        columns = left(columns)
    return columns @ vt


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("keep", [0, 1])
@pytest.mark.parametrize("filtered", [False, True])
@pytest.mark.parametrize("tau", [5.0, 0.3, 0.08])
def test_truncated_threshold_equals_the_exact_one(shape, keep, filtered, tau):
    x = _low_rank_plus_noise(shape)
    left = smoothing_filter(temporal_prior(shape[0], 50.0), 2.0) if filtered else None
    warm = lrr.WarmStart()
    y, nuclear = lrr.singular_value_threshold(x, tau, keep=keep, left=left, warm=warm)
    assert warm.calls == 1 and warm.fallbacks == 0  # the truncated route ran
    expected = _exact(x, tau, keep, left)
    assert np.linalg.norm(y - expected) <= 1e-8 * np.linalg.norm(expected)
    assert nuclear == pytest.approx(np.linalg.svd(expected, compute_uv=False).sum(), rel=1e-8)


@pytest.mark.parametrize("shape", SHAPES)
def test_truncated_threshold_matches_the_gram_route(shape):
    x = _low_rank_plus_noise(shape, seed=1)
    gram, gram_norm = lrr.singular_value_threshold(x, 0.2, keep=1)
    truncated, norm = lrr.singular_value_threshold(x, 0.2, keep=1, warm=lrr.WarmStart())
    assert np.linalg.norm(truncated - gram) <= 1e-8 * np.linalg.norm(gram)
    assert norm == pytest.approx(gram_norm, rel=1e-10)


def test_warm_start_settles_in_fewer_sweeps_than_a_cold_one():
    x = _low_rank_plus_noise(SHAPES[0], seed=2)
    rng = np.random.default_rng(3)
    nearby = x + 1e-3 * rng.standard_normal(x.shape)  # the next iteration's input, say
    warm = lrr.WarmStart()
    lrr.singular_value_threshold(x, 0.3, keep=1, warm=warm)
    before, surviving = warm.sweeps, warm.surviving
    y_warm, _ = lrr.singular_value_threshold(nearby, 0.3, keep=1, warm=warm)
    warm_sweeps = warm.sweeps - before
    cold = lrr.WarmStart(surviving=surviving)  # the same block width, random vectors
    y_cold, _ = lrr.singular_value_threshold(nearby, 0.3, keep=1, warm=cold)
    assert warm_sweeps < cold.sweeps
    assert_allclose(y_warm, y_cold, atol=1e-9 * np.abs(y_cold).max())


def test_warm_start_survives_a_permutation_of_the_columns():
    # The loop regroups points by permuting the columns of S#: the row-space vectors stay good.
    x = _low_rank_plus_noise(SHAPES[0], seed=4)
    warm = lrr.WarmStart()
    lrr.singular_value_threshold(x, 0.3, keep=1, warm=warm)
    before = warm.sweeps
    permuted = x[:, np.random.default_rng(5).permutation(x.shape[1])]
    lrr.singular_value_threshold(permuted, 0.3, keep=1, warm=warm)
    assert warm.sweeps - before == 1  # already settled: one sweep to check it


def test_the_block_grows_until_it_holds_a_value_below_the_threshold():
    # Warm-started from a rank-1 call, the next input has 12 values above tau: the block of
    # 1 + 1 + GUARD vectors has to widen.
    x = _low_rank_plus_noise(SHAPES[0], seed=6)
    warm = lrr.WarmStart()
    lrr.singular_value_threshold(x, 60.0, warm=warm)
    assert warm.surviving == 1
    y, _ = lrr.singular_value_threshold(x, 0.08, warm=warm)
    assert warm.surviving == 12 > 2 + leading_svd.GUARD and warm.fallbacks == 0
    expected = _exact(x, 0.08)
    assert np.linalg.norm(y - expected) <= 1e-8 * np.linalg.norm(expected)


def test_a_block_too_wide_falls_back_to_the_exact_route():
    shape = (400, 500)
    x = np.random.default_rng(7).standard_normal(shape)  # every value is above a small tau
    warm = lrr.WarmStart()
    y, _ = lrr.singular_value_threshold(x, 1.0, keep=1, warm=warm)
    assert warm.fallbacks == 1
    assert_allclose(y, _exact(x, 1.0, keep=1), atol=1e-9)
    # A smaller threshold leaves even more values above it: straight to the exact route.
    before = warm.sweeps
    y, _ = lrr.singular_value_threshold(x, 0.5, keep=1, warm=warm)
    assert warm.fallbacks == 2 and warm.sweeps == before
    assert_allclose(y, _exact(x, 0.5, keep=1), atol=1e-9)


def test_small_inputs_take_the_gram_route_whatever_the_warm_start():
    x = _low_rank_plus_noise((lrr.TRUNCATED_MIN_SIDE - 1, 900), seed=8)
    warm = lrr.WarmStart()
    y, _ = lrr.singular_value_threshold(x, 0.3, keep=1, warm=warm)
    assert warm.calls == 0
    assert np.array_equal(y, lrr.singular_value_threshold(x, 0.3, keep=1)[0])


def test_the_solve_with_the_truncated_threshold_matches_the_gram_route(monkeypatch):
    # Forced on a small problem (the loop takes the truncated route from 400 frames and points);
    # the temporal prior's filter and the unshrunk top value (free_mean_shape) are on. A weight
    # below MIN_DEPTH_PRIOR, so that the loop keeps the soft data term and the filter.
    data = make_sequence("face4", n_frames=60, n_points=150)
    params = SolverParams(rotations="known", n_groups=1, smoothness=1.0)
    gram = reconstruct(data.W, params, rotations=data.rotations)
    calls = []
    original = leading_svd.leading_triplets
    monkeypatch.setattr(lrr, "TRUNCATED_MIN_SIDE", 0)
    monkeypatch.setattr(
        leading_svd, "leading_triplets", lambda *args: calls.append(1) or original(*args)
    )
    truncated = reconstruct(data.W, params, rotations=data.rotations)
    assert len(calls) >= truncated.n_iter
    assert truncated.n_iter == gram.n_iter
    assert_allclose(truncated.shapes, gram.shapes, atol=1e-7 * np.abs(gram.shapes).max())


@pytest.mark.parametrize("shape", SHAPES)
def test_top_singular_value_of_a_large_matrix(shape):
    x = _low_rank_plus_noise(shape, seed=9)
    assert lrr.top_singular_value(x) == pytest.approx(np.linalg.norm(x, 2), rel=1e-12)
