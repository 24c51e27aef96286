"""The data-derived rules of completion/missing.py: each test fails when its rule is switched
off (the neutral settings of benchmarks/rule_ablation.py), on a seed the rule was not set on
(benchmarks/notes/2026-12-06-rule-ablation.md); the bound sits between the e3D with the rule
and without it. Known rotations, the closing occlusion (a band over 20 % of the width, 10 % of
the tracks lost, 2 % dropout)."""

from __future__ import annotations

import warnings

import numpy as np

from moju_core import SolverParams, reconstruct
from moju_core.datasets import make_sequence, occlusion_mask
from moju_core.metrics import e3d


def solve_occluded(name: str, n_frames: int, n_points: int, seed: int) -> float:
    """The ablation's solve under the closing occlusion: its e3D."""
    data = make_sequence(name, n_frames=n_frames, n_points=n_points, seed=seed)
    visibility = occlusion_mask(data, band=0.2, lost=0.1, dropout=0.02, seed=seed)
    W = np.where(np.repeat(visibility, 2, axis=0), data.W, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = reconstruct(
            W, SolverParams(seed=0), rotations=data.rotations, visibility=visibility, threads=1
        )
    return e3d(result.shapes, data.shapes)


def test_hidden_entries_of_high_leverage_are_not_fitted_as_data():
    """``TRUSTED_LEVERAGE``: 0.0140 with it, 0.090 trusting every hidden entry."""
    assert solve_occluded("face3", 99, 300, seed=302) < 0.03


def test_a_completion_that_misses_a_bodys_motion_is_not_fitted_as_data():
    """``MAX_UNEXPLAINED``: 0.076 with it, 0.126 trusting the body's completion."""
    assert solve_occluded("body-turn", 350, 41, seed=304) < 0.1
