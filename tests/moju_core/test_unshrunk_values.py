"""The unshrunk deformations of the S# step: the default rule, the switch after the first
iterations, and the depth it lets the loop create on a turning camera."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from moju_core import SolverParams, defaults, reconstruct
from moju_core.datasets import make_sequence
from moju_core.loop import lrr
from moju_core.loop.loop_state import loop_settings
from moju_core.metrics import e3d
from moju_core.spectrum import significant_rank


def _camera(yaw_degrees: np.ndarray, pitch_degrees: np.ndarray) -> np.ndarray:
    """(F, 2, 3) orthographic cameras: the first two rows of yaw-then-pitch rotations."""
    angles = np.stack([yaw_degrees, pitch_degrees, np.zeros_like(yaw_degrees)], axis=1)
    return Rotation.from_euler("yxz", angles, degrees=True).as_matrix()[:, :2, :]


def _oscillating_camera() -> np.ndarray:
    """60 frames swinging +-35 degrees in yaw and +-20 in pitch (periods 25 and 17 frames)."""
    frames = np.arange(60)
    return _camera(35 * np.sin(2 * np.pi * frames / 25), 20 * np.sin(2 * np.pi * frames / 17))


@pytest.mark.parametrize("name", ["face4", "bumps-turn"])
def test_a_slow_yaw_or_a_turntable_leaves_only_the_mean_shape_unshrunk(name: str) -> None:
    rotations = make_sequence(name, n_points=20).rotations
    assert defaults.trajectory_basis_size(rotations) < defaults.MIN_DEPTH_BASIS
    assert defaults.unshrunk_values(rotations) == 1


def test_an_oscillating_camera_leaves_the_leading_deformations_unshrunk() -> None:
    oscillating = _oscillating_camera()
    full = defaults.trajectory_basis_size(oscillating)
    assert full >= defaults.MIN_DEPTH_BASIS
    assert defaults.unshrunk_values(oscillating) == min(full, defaults.MAX_UNSHRUNK_VALUES)


def test_tracks_with_more_basis_shapes_than_the_cap_leave_as_many_unshrunk() -> None:
    oscillating = _oscillating_camera()
    full = defaults.trajectory_basis_size(oscillating)
    cap = defaults.MAX_UNSHRUNK_VALUES
    assert full > cap + 2  # the cameras resolve more than the cap
    assert defaults.unshrunk_values(oscillating, signal_rank=3 * cap) == cap
    assert defaults.unshrunk_values(oscillating, signal_rank=3 * (cap + 1) + 1) == cap + 2
    assert defaults.unshrunk_values(oscillating, signal_rank=3 * full + 3) == full


@pytest.mark.parametrize("n_shapes", [1, 2, 5, 8])
def test_the_shown_basis_shapes_of_random_shapes_are_their_number(n_shapes: int) -> None:
    """K random 3-D basis shapes under random cameras give a W of rank 3K."""
    rng = np.random.default_rng(n_shapes)
    n_frames, n_points = 80, 300
    bases = rng.standard_normal((n_shapes, 3, n_points))
    weights = rng.standard_normal((n_frames, n_shapes))
    shapes = np.einsum("fk,kcp->fcp", weights, bases)
    rotations = Rotation.random(n_frames, random_state=n_shapes).as_matrix()[:, :2, :]
    W = np.einsum("fjc,fcp->fjp", rotations, shapes).reshape(2 * n_frames, n_points)
    W -= W.mean(axis=1, keepdims=True)
    singular = np.linalg.svd(W, compute_uv=False)
    assert defaults.shown_basis_shapes(significant_rank(singular, W.shape)) == n_shapes


def test_a_body_under_an_oscillating_camera_leaves_more_than_the_cap_unshrunk() -> None:
    """Markers on 16 bones: more basis shapes than the cap, and cameras that resolve them."""
    data = make_sequence("body-osc", seed=0)
    result = reconstruct(data.W, SolverParams(), rotations=data.rotations)
    assert result.params.unshrunk_values > defaults.MAX_UNSHRUNK_VALUES


@pytest.mark.parametrize("limit", [1, 2, 3, 4, 6])
def test_the_limited_basis_size_is_the_full_one_capped(limit: int) -> None:
    rotations = make_sequence("face3", n_points=20).rotations
    full = defaults.trajectory_basis_size(rotations)
    assert defaults.trajectory_basis_size(rotations, limit=limit) == min(full, limit)


def test_noisy_tracks_resolve_to_the_mean_shape_only_before_the_smoothness_trials() -> None:
    rotations = make_sequence("face3", n_points=20).rotations
    assert defaults.unshrunk_values(rotations) > 1
    quiet, noisy = (
        defaults.resolve(SolverParams(), 99, 2000, 1.0, rotations=rotations, noise=noise)
        for noise in (0.0, 10 * defaults.EXACT_DATA_NOISE)
    )
    assert quiet.unshrunk_values > 1 and noisy.unshrunk_values == 1


def test_noisy_tracks_solve_with_only_the_mean_shape_unshrunk() -> None:
    data = make_sequence("paper", n_points=200, n_frames=30, noise=0.02)
    result = reconstruct(data.W, SolverParams(smoothness=100.0), rotations=data.rotations)
    assert defaults.unshrunk_values(data.rotations) > 1  # the cameras alone would allow more
    assert result.params.unshrunk_values == 1


def test_the_loop_keeps_the_mean_shape_only_for_the_first_iterations() -> None:
    params = defaults.resolve(
        SolverParams(unshrunk_values=3, smoothness=0.0, n_groups=1), 10, 20, 1.0
    )
    assert params.free_mean_shape
    settings = loop_settings(params, 10, 20)
    after = defaults.UNSHRINK_AFTER
    assert [settings.kept_at(i) for i in (1, after, after + 1, 300)] == [1, 1, 3, 3]


def test_user_values_are_kept_and_the_default_is_recorded() -> None:
    data = make_sequence("bumps-osc", n_points=200, n_frames=30)
    given = reconstruct(data.W, SolverParams(unshrunk_values=2), rotations=data.rotations)
    assert given.params.unshrunk_values == 2
    derived = reconstruct(data.W, SolverParams(), rotations=data.rotations)
    assert derived.params.unshrunk_values in range(1, defaults.MAX_UNSHRUNK_VALUES + 1)
    if derived.params.smoothness < defaults.MIN_DEPTH_PRIOR:
        assert derived.params.unshrunk_values == 1
    bmm = reconstruct(data.W, SolverParams(method="bmm"), rotations=data.rotations)
    assert bmm.params.unshrunk_values == 0


def test_the_unshrunk_step_is_the_prox_of_the_partial_sum() -> None:
    """What the S# step computes with ``keep = k``: the minimiser of
    ``tau * sum_{i > k} sigma_i(Y) + 0.5 ||Y - X||^2`` (checked against perturbations)."""
    rng = np.random.default_rng(3)
    x = rng.standard_normal((12, 30))
    tau, keep = 1.5, 3
    y, _ = lrr.singular_value_threshold(x, tau, keep=keep)

    def objective(candidate: np.ndarray) -> float:
        singular = np.linalg.svd(candidate, compute_uv=False)
        return tau * singular[keep:].sum() + 0.5 * np.sum((candidate - x) ** 2)

    best = objective(y)
    for _ in range(50):
        assert objective(y + 1e-3 * rng.standard_normal(y.shape)) >= best - 1e-12


def test_a_flat_sheet_is_not_a_fixed_point_on_a_turning_camera() -> None:
    """Bumps growing and shrinking under an oscillating camera, known rotations: the zero-depth
    start is left far behind, and the unshrunk deformations are what move it."""
    data = make_sequence("bumps-osc", n_points=600, seed=0)
    tracks = data.W - data.W.mean(axis=1, keepdims=True)
    flat = np.einsum("fji,fjp->fpi", data.rotations, tracks.reshape(data.n_frames, 2, -1))
    flat_error = e3d(flat, data.shapes)
    params = SolverParams(smoothness=10.0, seed=0)
    default = reconstruct(data.W, params, rotations=data.rotations)
    assert default.params.unshrunk_values > 1
    shrunk = reconstruct(
        data.W, params.model_copy(update={"unshrunk_values": 1}), rotations=data.rotations
    )
    assert e3d(default.shapes, data.shapes) < 0.5 * flat_error
    assert e3d(default.shapes, data.shapes) < 0.85 * e3d(shrunk.shapes, data.shapes)
