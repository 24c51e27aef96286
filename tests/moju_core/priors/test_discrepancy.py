"""The nuclear-norm weight of noisy tracks by the discrepancy principle."""

from __future__ import annotations

import warnings

import numpy as np

from moju_core import SolverParams, reconstruct, solver
from moju_core.datasets import make_sequence
from moju_core.metrics import evaluate
from moju_core.priors.discrepancy import discrepancy, next_weight


def test_the_discrepancy_of_the_truth_is_one_for_white_noise():
    rng = np.random.default_rng(0)
    rotations = np.stack([np.eye(3)[:2]] * 40)
    shapes = rng.standard_normal((40, 3, 500))
    shapes -= shapes.mean(axis=2, keepdims=True)
    tracks = np.einsum("fij,fjp->fip", rotations, shapes) + 0.1 * rng.standard_normal((40, 2, 500))
    tracks -= tracks.mean(axis=2, keepdims=True)
    assert abs(discrepancy(tracks, rotations, shapes, 0.01) - 1.0) < 0.02
    # A fit that reproduces the noisy tracks has absorbed all of it.
    fitted = np.concatenate([tracks, np.zeros((40, 1, 500))], axis=1)
    assert discrepancy(tracks, rotations, fitted, 0.01) < 1e-20


def test_the_next_weight_grows_as_one_over_the_root_of_the_discrepancy_and_is_bounded():
    assert np.isclose(next_weight(2.0, 0.25), 4.0)
    assert next_weight(2.0, 0.0) == 32.0


def _solve(data, weigh: bool):
    keep = solver._weigh_by_discrepancy
    if not weigh:
        solver._weigh_by_discrepancy = lambda out, solve, again: out
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            params = SolverParams(seed=0, rotations="known")
            result = reconstruct(data.W, params, rotations=data.rotations)
    finally:
        solver._weigh_by_discrepancy = keep
    return result, evaluate(result.shapes, data.shapes)["e3d_procrustes"]


def test_markers_at_heavy_noise_no_longer_take_the_noise_as_deformation():
    """41 markers x 350 frames at 5.5 % noise, true cameras: the default weight leaves 1 % of
    the noise in the residual (e3D 0.21); weighted by the discrepancy, 0.13, as a plain
    nuclear-norm solve at its best weight (0.135)."""
    data = make_sequence("body-osc", noise=0.055, seed=10)
    weighed, weighed_error = _solve(data, weigh=True)
    default, default_error = _solve(data, weigh=False)
    assert weighed.params.beta2 > 4 * default.params.beta2
    assert weighed_error < 0.75 * default_error


def test_a_fit_that_leaves_the_noise_keeps_its_weight():
    """A face at 3 % noise: the default weight already leaves the noise in the residual, so no
    second solve (the weight is unchanged)."""
    data = make_sequence("face3", n_frames=40, n_points=200, noise=0.03, seed=10)
    weighed, _ = _solve(data, weigh=True)
    default, _ = _solve(data, weigh=False)
    assert weighed.params.beta2 == default.params.beta2
