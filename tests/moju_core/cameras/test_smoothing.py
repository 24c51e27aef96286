"""Given rotations: jitter removed by cross-validated smoothing, smooth paths left as they are."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from moju_core import SolverParams, reconstruct, solver
from moju_core.cameras.smoothing import is_ordered_path, smooth_rotations
from moju_core.datasets import make_sequence, perturb_rotations
from moju_core.metrics import evaluate, rotation_errors_deg


@pytest.mark.parametrize("name", ["face1", "face3", "face4", "paper", "body-osc", "flag-osc"])
def test_a_smooth_camera_path_is_returned_unchanged(name):
    rotations = make_sequence(name, n_points=50, seed=3).rotations
    smoothed, weight = smooth_rotations(rotations)
    assert weight == 0.0
    assert smoothed is rotations


@pytest.mark.parametrize("name", ["face3", "body-turn"])
def test_jitter_of_one_degree_per_frame_is_mostly_removed(name):
    truth = make_sequence(name, n_points=50, seed=4).rotations
    given = perturb_rotations(truth, 1.0, seed=5)
    smoothed, weight = smooth_rotations(given)
    assert weight > 0.0
    before = rotation_errors_deg(given, truth).mean()
    assert rotation_errors_deg(smoothed, truth).mean() < 0.5 * before
    gram = smoothed @ np.swapaxes(smoothed, 1, 2)
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(2), gram.shape), atol=1e-12)


def test_too_few_frames_to_judge_are_used_as_given():
    rotations = make_sequence("face1", n_points=50, seed=0).rotations[:3]
    smoothed, weight = smooth_rotations(rotations)
    assert weight == 0.0 and smoothed is rotations


def _known_solve(data, rotations):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = reconstruct(data.W, SolverParams(seed=0, rotations="known"), rotations=rotations)
    return result, evaluate(result.shapes, data.shapes)["e3d_procrustes"]


def test_the_solver_smooths_jittery_given_rotations_and_gains_from_it(monkeypatch):
    """A face (40 frames) with its true rotations turned by 1 degree per frame: e3D 0.10 as
    given, 0.037 once smoothed (the jitter misleads the temporal prior's choice)."""
    data = make_sequence("face3", n_frames=40, n_points=150, seed=10)
    given = perturb_rotations(data.rotations, 1.0, seed=110)
    result, smoothed_error = _known_solve(data, given)
    assert result.diagnostics.plan.rotation_smoothing > 0.0
    monkeypatch.setattr(solver, "smooth_rotations", lambda rotations: (rotations, 0.0))
    _, given_error = _known_solve(data, given)
    assert smoothed_error < 0.5 * given_error


@pytest.mark.parametrize("n_frames", [5, 30, 100])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_views_in_no_particular_order_are_not_smoothed(n_frames, seed):
    """Known rotations of an unordered set of views (random, or turns about one axis in random
    order) are not a smooth path with small errors: smoothing them would move them by tens of
    degrees, so they are used as given."""
    scattered = Rotation.random(n_frames, random_state=seed).as_matrix()[:, :2]
    angles = np.random.default_rng(seed).uniform(-80.0, 80.0, (n_frames, 1))
    turns = Rotation.from_euler("y", angles, degrees=True).as_matrix()[:, :2]
    for rotations in (scattered, turns):
        assert not is_ordered_path(rotations.reshape(n_frames, 6))
        smoothed, weight = smooth_rotations(rotations)
        assert weight == 0.0 and smoothed is rotations


def test_a_camera_path_with_jitter_is_still_a_path():
    truth = make_sequence("flag-osc", n_points=50, seed=0).rotations
    assert is_ordered_path(perturb_rotations(truth, 1.0, seed=1).reshape(len(truth), 6))
