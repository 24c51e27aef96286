"""The data-derived rules of defaults.py and solve_plan.py: each test fails when its rule is
switched off (the neutral settings of benchmarks/rule_ablation.py).

Each is one small seeded solve on a seed the rules were not set on (held-out seeds 301-306 of
the ablation, benchmarks/notes/2026-12-06-rule-ablation.md), where the rule's effect is large:
the bound sits between the e3D with the rule and without it.
"""

from __future__ import annotations

import warnings

from moju_core import SolverParams, reconstruct
from moju_core.datasets import make_sequence
from moju_core.metrics import e3d


def solve(
    name: str, n_frames: int, n_points: int, seed: int, noise: float = 0.0, known: bool = True
):
    """The ablation's solve: default parameters, known rotations (or the solver's own); the
    result and its e3D."""
    data = make_sequence(name, n_frames=n_frames, n_points=n_points, seed=seed, noise=noise)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rotations = data.rotations if known else None
        result = reconstruct(data.W, SolverParams(seed=0), rotations=rotations, threads=1)
    return result, e3d(result.shapes, data.shapes)


def test_noise_free_tracks_are_fitted_exactly():
    """``defaults.EXACT_DATA_NOISE`` (``solve_plan.exact_data``): 0.0125 with the rule, 0.0204
    with every track taken as noisy."""
    result, error = solve("face3", 99, 300, seed=303)
    assert result.exact_fit
    assert error < 0.016


def test_a_turning_camera_leaves_the_leading_deformations_unshrunk():
    """``defaults.unshrunk_values`` (``MAX_UNSHRUNK_VALUES``, ``MIN_DEPTH_BASIS``): 0.045 with
    the rule, 0.098 with the mean shape alone unshrunk."""
    result, error = solve("bumps-osc", 60, 300, seed=303)
    assert result.params.unshrunk_values > 1
    assert error < 0.07


def test_estimated_cameras_leave_the_deformations_unshrunk_only_after_the_first_iterations():
    """``defaults.UNSHRINK_AFTER``: 0.0094 with it, 0.0232 with the values left unshrunk from
    the first iteration (the paper, its own cameras, refined in the loop)."""
    result, error = solve("paper", 60, 300, seed=303, known=False)
    assert result.params.unshrunk_values > 1
    assert error < 0.015


def test_noisy_tracks_of_an_oscillating_sheet_take_the_signal_fit():
    """``solve_plan.tries_signal_fit``: 0.047 with the rule, 0.178 fitted softly."""
    result, error = solve("bumps-osc", 60, 300, seed=303, noise=0.01)
    assert result.diagnostics.signal_fit
    assert error < 0.1
