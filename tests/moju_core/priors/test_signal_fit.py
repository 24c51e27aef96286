"""The exact fit of noisy tracks projected onto their signal subspace
(moju_core.priors.signal_fit)."""

from __future__ import annotations

import numpy as np
import pytest

from moju_core import SolverParams, reconstruct
from moju_core.datasets import make_sequence, occlusion_mask
from moju_core.loop import admm
from moju_core.metrics import e3d
from moju_core.validation import with_missing


@pytest.fixture(scope="module")
def noisy_oscillating_sheet():
    return make_sequence("bumps-osc", n_points=1_000, noise=0.01, seed=0)


@pytest.fixture(scope="module")
def signal_fitted(noisy_oscillating_sheet):
    data = noisy_oscillating_sheet
    return reconstruct(data.W, SolverParams(seed=0), rotations=data.rotations)


def test_noisy_sheet_under_an_oscillating_camera_takes_the_noise_free_settings(signal_fitted):
    result = signal_fitted
    assert result.diagnostics.signal_fit
    # The exact fit's depth-setting weight and unshrunk deformations, as for noise-free tracks.
    assert result.params.smoothness >= 10.0
    assert result.params.unshrunk_values > 1


def test_the_signal_fit_recovers_depth_the_soft_fit_loses(noisy_oscillating_sheet, signal_fitted):
    data = noisy_oscillating_sheet
    # The soft rule's own choice, given explicitly: the solve as it ran before the signal fit.
    weak_weight = SolverParams(seed=0, smoothness=1.0)
    soft = reconstruct(data.W, weak_weight, rotations=data.rotations)
    assert not soft.diagnostics.signal_fit
    assert e3d(signal_fitted.shapes, data.shapes) < 0.5 * e3d(soft.shapes, data.shapes)


def test_a_soft_weight_of_ten_takes_it_too():
    # The cloth's soft rule chooses exactly 10: the projection's exact fit still sets the
    # depths better (unshrunk deformations, no pull against the observed motion).
    data = make_sequence("cloth", n_points=1_000, noise=0.01, seed=0)
    result = reconstruct(data.W, SolverParams(seed=0), rotations=data.rotations)
    assert result.diagnostics.signal_fit
    soft = reconstruct(data.W, SolverParams(seed=0, smoothness=10.0), rotations=data.rotations)
    assert e3d(result.shapes, data.shapes) < 0.9 * e3d(soft.shapes, data.shapes)


def test_short_sequences_keep_the_soft_fit_unchanged():
    data = make_sequence("face1", n_points=600, noise=0.02, seed=1)
    result = reconstruct(data.W, SolverParams(seed=1), rotations=data.rotations)
    assert not result.diagnostics.signal_fit
    assert result.params.smoothness < 10.0
    same = reconstruct(
        data.W, SolverParams(seed=1, smoothness=result.params.smoothness), rotations=data.rotations
    )
    np.testing.assert_array_equal(result.shapes, same.shapes)


def test_noise_free_or_estimated_camera_solves_never_take_it():
    clean = make_sequence("bumps-osc", n_points=400, seed=1)
    assert not reconstruct(clean.W, rotations=clean.rotations).diagnostics.signal_fit
    noisy = make_sequence("bumps-osc", n_points=400, noise=0.01, seed=1)
    # An exact fit trusts the cameras; estimated ones keep the soft fit.
    assert not reconstruct(noisy.W, SolverParams(seed=1)).diagnostics.signal_fit


def _count_loops(monkeypatch) -> list[int]:
    calls: list[int] = []
    run = admm.run

    def counted(*args, **kwargs):
        calls.append(1)
        return run(*args, **kwargs)

    monkeypatch.setattr(admm, "run", counted)
    return calls


def test_complete_tracks_take_the_exact_weight_from_the_smoothness_trials(
    noisy_oscillating_sheet, signal_fitted, monkeypatch
):
    """One set of trial solves, then the loop: the exact fit's rule reads the trials that
    chose the soft weight (they ran on the same projection)."""
    data = noisy_oscillating_sheet
    calls = _count_loops(monkeypatch)
    again = reconstruct(data.W, SolverParams(seed=0), rotations=data.rotations)
    assert again.diagnostics.signal_fit
    assert len(calls) == len(again.diagnostics.smoothness_trials) + 1
    np.testing.assert_array_equal(again.shapes, signal_fitted.shapes)


@pytest.fixture(scope="module")
def occluded_noisy_sheet():
    data = make_sequence("bumps-osc", n_points=1_000, noise=0.02, seed=0)
    visibility = occlusion_mask(data, band=0.2, lost=0.1, dropout=0.02, seed=0)
    return data, with_missing(data.W, visibility), visibility


def test_noisy_tracks_with_missing_entries_take_it_on_their_completion(
    occluded_noisy_sheet, monkeypatch
):
    data, W, visibility = occluded_noisy_sheet
    calls = _count_loops(monkeypatch)
    result = reconstruct(W, SolverParams(seed=0), rotations=data.rotations, visibility=visibility)
    assert result.diagnostics.signal_fit
    assert result.params.smoothness >= 10.0
    # The soft rule's trials fitted the observed entries only; the projected completion
    # (every entry) gets trials of its own before the loop.
    assert len(calls) > len(result.diagnostics.smoothness_trials) + 1
    np.testing.assert_array_equal(result.visibility, visibility)
    # The soft fit the solver used before, at the weight its rule chose on the observed entries.
    soft = reconstruct(
        W, SolverParams(seed=0, smoothness=1.0), rotations=data.rotations, visibility=visibility
    )
    assert not soft.diagnostics.signal_fit
    # Measured: 0.112 against 0.195.
    assert e3d(result.shapes, data.shapes) < 0.7 * e3d(soft.shapes, data.shapes)
