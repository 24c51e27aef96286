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


def test_smoothed_starts_keep_the_cheapest_rounds(small_program, monkeypatch):
    own = solve_max_depth_cone(*small_program)
    runs: list[tuple[float, np.ndarray]] = []
    rounds = cone_program._consistency_rounds

    def recorded(program, cost, best, start, status, **kwargs):
        result = rounds(program, cost, best, start, status, **kwargs)
        runs.append((float(cost @ result[1]), cone_program._unpack(program.pairs, result[1])[0]))
        return result

    monkeypatch.setattr(cone_program, "_consistency_rounds", recorded)
    chosen = solve_max_depth_cone(*small_program, smoothed_starts=True)
    assert len(runs) == 3  # the own start, then the bent and local-plane starts
    assert chosen.status == "Solved" and chosen.n_solves > own.n_solves
    np.testing.assert_array_equal(runs[0][1], own.depths)  # the own start is today's solve
    cheapest = min(runs, key=lambda run: run[0])[1]
    np.testing.assert_array_equal(chosen.depths, cheapest)


def test_pair_scale_is_the_edge_scale_when_every_image_sees_every_edge(small_program):
    edges_scale = solve_max_depth_cone(*small_program, length_scale="edges")
    pairs_scale = solve_max_depth_cone(*small_program, length_scale="pairs")
    assert pairs_scale.status == "Solved"
    np.testing.assert_allclose(pairs_scale.depths, edges_scale.depths, rtol=1e-5)
    np.testing.assert_allclose(pairs_scale.lengths, edges_scale.lengths, rtol=1e-5)


def _half_seen_sheet():
    """A sheet whose right half is seen in 2 of 8 images only."""
    rays, truth = cylinder_sheet(n_points=60, n_frames=8, seed=5)
    seen = np.ones(rays.shape[:2], bool)
    seen[2:, truth[0, :, 0] > np.median(truth[0, :, 0])] = False
    return rays, seen, truth


def test_pair_scale_means_one_over_the_pairs_and_keeps_rarely_seen_lengths():
    rays, seen, truth = _half_seen_sheet()
    edges = neighbour_edges(rays, seen, k=6)
    counts = (seen[:, edges[:, 0]] & seen[:, edges[:, 1]]).sum(axis=0)
    true_lengths = np.linalg.norm(truth[0, edges[:, 0]] - truth[0, edges[:, 1]], axis=1)
    bias = {}
    for scale in ("edges", "pairs"):
        solution = solve_max_depth_cone(rays, seen, edges, length_scale=scale)
        used = np.isfinite(solution.lengths)
        weights = counts[used] if scale == "pairs" else np.ones(used.sum())
        assert np.average(solution.lengths[used], weights=weights) == pytest.approx(1.0)
        ratio = solution.lengths[used] / true_lengths[used]
        rare = counts[used] <= 2
        bias[scale] = abs(np.log(np.median(ratio[~rare]) / np.median(ratio[rare])))
    # The edge scale trades the rarely seen edges' length for the often seen ones'.
    assert bias["pairs"] < 0.5 * bias["edges"]


def test_an_unknown_length_scale_is_refused(small_program):
    with pytest.raises(ValueError, match="length_scale"):
        solve_max_depth_cone(*small_program, length_scale="points")


def test_auto_scale_keeps_the_solution_closer_to_an_isometry():
    rays, seen, _ = _half_seen_sheet()
    edges = neighbour_edges(rays, seen, k=6)
    solved = {
        scale: solve_max_depth_cone(rays, seen, edges, length_scale=scale)
        for scale in ("edges", "pairs")
    }
    residual = {
        s: cone_program.isometry_residual(rays, edges, solution.depths, solution.lengths)
        for s, solution in solved.items()
    }
    assert residual["edges"] != residual["pairs"]
    auto = solve_max_depth_cone(rays, seen, edges)  # the default
    kept = min(residual, key=residual.get)
    np.testing.assert_array_equal(auto.depths, solved[kept].depths)
    assert auto.length_scale == kept
    assert auto.n_solves == solved["edges"].n_solves + solved["pairs"].n_solves


def test_auto_scale_solves_once_when_every_image_sees_every_edge(small_program):
    auto = solve_max_depth_cone(*small_program)  # the default
    edges_scale = solve_max_depth_cone(*small_program, length_scale="edges")
    np.testing.assert_array_equal(auto.depths, edges_scale.depths)
    assert auto.n_solves == edges_scale.n_solves


def test_isometry_residual_is_zero_for_shapes_that_keep_their_lengths():
    _, bent = cylinder_sheet(n_points=40, n_frames=1, seed=2)
    shape = bent[0] - bent[0].mean(axis=0)
    turns = [np.eye(3), _turn_about_y(0.2), _turn_about_y(-0.3)]
    truth = np.stack([shape @ turn.T + [0.0, 0.1 * f, 3.0] for f, turn in enumerate(turns)])
    rays = truth[..., :2] / truth[..., 2:]
    edges = neighbour_edges(rays, k=6)
    depths = truth[..., 2]
    lengths = np.linalg.norm(shape[edges[:, 0]] - shape[edges[:, 1]], axis=1)
    assert cone_program.isometry_residual(rays, edges, depths, lengths) < 1e-9
    assert cone_program.isometry_residual(rays, edges, 1.1 * depths, lengths) == pytest.approx(0.1)


def _turn_about_y(angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` radians about the y axis."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
