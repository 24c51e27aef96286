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


def solve_occluded(name: str, n_frames: int, n_points: int, seed: int, known: bool = True) -> float:
    """The ablation's solve under the closing occlusion (known rotations, or the solver's
    own): its e3D."""
    data = make_sequence(name, n_frames=n_frames, n_points=n_points, seed=seed)
    visibility = occlusion_mask(data, band=0.2, lost=0.1, dropout=0.02, seed=seed)
    W = np.where(np.repeat(visibility, 2, axis=0), data.W, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = reconstruct(
            W,
            SolverParams(seed=0),
            rotations=data.rotations if known else None,
            visibility=visibility,
            threads=1,
        )
    return e3d(result.shapes, data.shapes)


def test_hidden_entries_of_high_leverage_are_not_fitted_as_data():
    """``TRUSTED_LEVERAGE``: 0.0140 with it, 0.090 trusting every hidden entry."""
    assert solve_occluded("face3", 99, 300, seed=302) < 0.03


def test_a_completion_that_misses_a_bodys_motion_is_not_fitted_as_data():
    """``MAX_UNEXPLAINED``: 0.076 with it, 0.126 trusting the body's completion."""
    assert solve_occluded("body-turn", 350, 41, seed=304) < 0.1


def test_the_rank_search_looks_past_one_rank_that_misses_the_held_out_entries():
    """``OVERFIT_PATIENCE``: 0.0090 with it, 0.0227 stopping at the first rank with twice the
    best held-out error (rank 3 instead of 6; with the paper's own cameras 0.012 against 0.30)."""
    assert solve_occluded("paper", 60, 300, seed=320) < 0.015


def test_the_rank_is_chosen_on_runs_of_held_out_frames_too():
    """``HOLD_OUT_RUN_POINTS``, ``HOLD_OUT_RUN_LENGTH``: face4's 41 markers, 0.0228 with runs of
    frames held out, 0.0260 with random entries only (a small effect: held-out mean 0.0409
    against 0.0420 on seeds 301-306)."""
    assert solve_occluded("face4", 350, 41, seed=305) < 0.0245


def test_the_noise_of_a_short_sequence_is_read_from_five_frame_blocks():
    """``NOISE_WINDOWS``: ten frames of face1, 0.0369 with the 5-frame blocks, 0.0408 without."""
    assert solve_occluded("face1", 10, 300, seed=303) < 0.039


def test_the_exact_model_tries_directions_beyond_the_windows_rank():
    """``EXTRA_DIRECTIONS``: face3 with its own cameras, 0.014 with them, 0.027 without."""
    assert solve_occluded("face3", 99, 300, seed=302, known=False) < 0.02
