"""The number of shape bases from the spectrum, and the checks of W for the estimators."""

from __future__ import annotations

import numpy as np
import pytest
from low_rank_sequences import make_sequence

from moju_core.cameras import estimate_cameras
from moju_core.cameras.bases import choose_n_bases, min_frames_for_bases
from moju_core.cameras.intersection import intersection_rotations
from moju_core.cameras.rigid import rigid_rotations
from moju_core.errors import MeasurementError


def _intersection(W: np.ndarray, n_bases: int | None = None, *, seed: int = 0) -> np.ndarray:
    """Intersection rotations with K chosen from the spectrum unless given."""
    return estimate_cameras(W, "intersection", n_bases=n_bases, seed=seed).rotations


# ----------------------------------------------------------------------------------------
# Number of shape bases
# ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_bases", [1, 2, 3, 4, 5])
def test_choose_n_bases_recovers_k_without_noise(n_bases):
    W, _, _ = make_sequence(n_frames=60, n_points=400, n_bases=n_bases, seed=n_bases)
    assert choose_n_bases(W) == n_bases


@pytest.mark.parametrize("n_bases", [1, 2, 3, 4])
def test_choose_n_bases_with_noise_does_not_inflate_k(n_bases):
    for noise in (0.01, 0.055):
        W, _, _ = make_sequence(n_frames=60, n_points=400, n_bases=n_bases, seed=10, noise=noise)
        chosen = choose_n_bases(W)
        # Measured: exactly K at 1 % noise; at 5.5 % a weak basis may sink below the noise.
        assert n_bases - 1 <= chosen <= n_bases + 1
        if noise == 0.01:
            assert chosen == n_bases


def test_choose_n_bases_on_pure_noise_and_its_bounds():
    noise = np.random.default_rng(11).normal(size=(80, 500))
    assert choose_n_bases(noise - noise.mean(axis=1, keepdims=True)) == 1
    W, _, _ = make_sequence(n_frames=60, n_points=400, n_bases=4, seed=12)
    assert choose_n_bases(W, max_bases=2) == 2
    # Ten frames support at most two bases (min_frames_for_bases(3) == 15).
    W, _, _ = make_sequence(n_frames=10, n_points=400, n_bases=4, seed=12)
    assert choose_n_bases(W) == 2
    assert [min_frames_for_bases(k) for k in (1, 2, 3, 4, 5)] == [3, 8, 15, 25, 38]
    with pytest.raises(ValueError, match="max_bases"):
        choose_n_bases(W, max_bases=0)


# ----------------------------------------------------------------------------------------
# Validation
# ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("function", [_intersection, rigid_rotations, choose_n_bases])
def test_malformed_measurements_are_rejected(function):
    W, _, _ = make_sequence(n_frames=10, n_points=50, n_bases=1, seed=16)
    with pytest.raises(MeasurementError, match="needs an even number"):
        function(W[:-1])
    with pytest.raises(MeasurementError, match="needs 2 dimensions"):
        function(W[0])
    bad = W.copy()
    bad[3, 7] = np.nan
    with pytest.raises(MeasurementError, match="NaN"):
        function(bad)
    with pytest.raises(MeasurementError, match="at least 3 frames"):
        function(W[:4])


def test_too_small_problems_are_rejected_with_clear_messages():
    W, _, _ = make_sequence(n_frames=20, n_points=9, n_bases=1, seed=17)
    with pytest.raises(MeasurementError, match="at least 10 tracked points, got 9"):
        intersection_rotations(W, 3)
    with pytest.raises(MeasurementError, match="at least 4 tracked points"):
        rigid_rotations(W[:, :3])
    with pytest.raises(MeasurementError, match="n_bases=4 needs at least 25 frames"):
        _intersection(W, n_bases=4)
    with pytest.raises(MeasurementError, match="zero"):
        intersection_rotations(np.zeros((20, 30)), 2)


def test_bad_arguments_are_rejected():
    W, _, _ = make_sequence(n_frames=20, n_points=50, n_bases=1, seed=18)
    with pytest.raises(ValueError, match="n_bases must be a positive integer, got 0"):
        intersection_rotations(W, 0)
    with pytest.raises(ValueError, match="n_bases must be a positive integer"):
        _intersection(W, n_bases=2.5)
