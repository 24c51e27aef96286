"""The data-derived rules of priors/smoothness.py: each test fails when its rule is switched off
(the neutral settings of benchmarks/rule_ablation.py), on a seed the rule was not set on
(benchmarks/notes/2026-12-06-rule-ablation.md); the bound sits between the e3D with the rule
and without it."""

from __future__ import annotations

import warnings

from moju_core import SolverParams, reconstruct
from moju_core.datasets import make_sequence
from moju_core.metrics import e3d


def solve(name: str, n_frames: int, n_points: int, seed: int):
    """The ablation's solve: default parameters, known rotations; the result and its e3D."""
    data = make_sequence(name, n_frames=n_frames, n_points=n_points, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = reconstruct(data.W, SolverParams(seed=0), rotations=data.rotations, threads=1)
    return result, e3d(result.shapes, data.shapes)


def test_ten_frames_of_changing_expressions_get_a_weak_prior():
    """``DEFORMATION_ALLOWANCE`` over ``SMOOTHNESS_GRID``: 0.045 with the chosen weight, 0.159
    with the depth-setting weight 10 for every sequence."""
    result, error = solve("face1", 10, 300, seed=301)
    assert result.params.smoothness < 10
    assert error < 0.08


def test_an_exact_fit_of_a_waving_flag_takes_the_depth_setting_weight():
    """``EXACT_FIT_ALLOWANCE``: 0.108 with it, 0.182 with the soft rule's weight."""
    result, error = solve("flag-osc", 60, 300, seed=306)
    assert result.exact_fit and result.params.smoothness == 10
    assert error < 0.145
