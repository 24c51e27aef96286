"""The cone program's solver settings (moju_core.priors.cone_program)."""

from __future__ import annotations

import numpy as np
import pytest

from moju_core.datasets.perspective_sheets import cylinder_sheet
from moju_core.priors import cone_program
from moju_core.priors.cone_program import solve_max_depth_cone
from moju_core.priors.neighbour_graph import neighbour_edges


@pytest.fixture(scope="module")
def small_program():
    rays, _ = cylinder_sheet(n_points=40, n_frames=4, seed=3)
    seen = np.ones(rays.shape[:2], bool)
    return rays, seen, neighbour_edges(rays, k=6)


def test_the_faster_settings_give_the_defaults_solution(small_program, monkeypatch):
    fast = solve_max_depth_cone(*small_program, n_rounds=0)
    monkeypatch.setattr(cone_program, "CLARABEL_SETTINGS", {})
    default = solve_max_depth_cone(*small_program, n_rounds=0)
    # The optimum is flat along some depths: equal to well within the tracks' noise, not
    # bit for bit.
    assert fast.status == default.status == "Solved"
    np.testing.assert_allclose(fast.depths, default.depths, rtol=1e-3)


def test_settings_that_fail_fall_back_to_the_defaults(small_program, monkeypatch):
    monkeypatch.setattr(cone_program, "CLARABEL_SETTINGS", {})
    default = solve_max_depth_cone(*small_program, n_rounds=0)
    monkeypatch.setattr(cone_program, "CLARABEL_SETTINGS", {"max_iter": 1})
    solved = solve_max_depth_cone(*small_program, n_rounds=0)
    assert solved.status == "Solved"
    np.testing.assert_allclose(solved.depths, default.depths)
