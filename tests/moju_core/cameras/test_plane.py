"""Rotations from the calibration of a sheet's dominant plane: exact recovery on rigid sheets,
the choice of side in every frame, the groups' L1 weights and the one-group ablation."""

import numpy as np
import pytest

from moju_core.cameras import estimate_cameras, plane
from moju_core.cameras.refinement import project_to_stiefel
from moju_core.datasets import make_sequence
from moju_core.metrics import rotation_errors_deg

D = np.diag([1.0, 1.0, -1.0])


def _camera(n_frames: int, seed: int = 0) -> np.ndarray:
    """An oscillating camera: yaw +-40 degrees (period 30 frames), pitch +-12 (period 51),
    full rotations (F, 3, 3). The sheet's normal is z."""
    frames = np.arange(n_frames, dtype=np.float64)
    phase = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, 2)
    yaw = np.radians(40.0) * np.sin(2 * np.pi * frames / 30.0 + phase[0])
    pitch = np.radians(12.0) * np.sin(2 * np.pi * frames / 51.0 + phase[1])
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    Ry = np.zeros((n_frames, 3, 3))
    Ry[:, 0, 0] = Ry[:, 2, 2] = cy
    Ry[:, 0, 2], Ry[:, 2, 0] = sy, -sy
    Ry[:, 1, 1] = 1.0
    Rx = np.zeros((n_frames, 3, 3))
    Rx[:, 1, 1] = Rx[:, 2, 2] = cp
    Rx[:, 1, 2], Rx[:, 2, 1] = -sp, sp
    Rx[:, 0, 0] = 1.0
    return Rx @ Ry


def _sheet(n_points: int, seed: int = 0, relief: float = 0.0) -> np.ndarray:
    """A 1.4 x 1 sheet in the xy-plane with a little rigid relief in z, (P, 3)."""
    rng = np.random.default_rng(seed)
    points = np.column_stack(
        [rng.uniform(-0.7, 0.7, n_points), rng.uniform(-0.5, 0.5, n_points), np.zeros(n_points)]
    )
    points[:, 2] = relief * np.sin(3.0 * points[:, 0]) * np.cos(2.0 * points[:, 1])
    return points


def _project(rotations: np.ndarray, shapes: np.ndarray) -> np.ndarray:
    """Tracks (2F, P) of shapes (F, P, 3) or one shape (P, 3) under rotations (F, 2, 3)."""
    if shapes.ndim == 2:
        shapes = np.broadcast_to(shapes, (rotations.shape[0], *shapes.shape))
    return np.einsum("fij,fpj->fip", rotations, shapes).reshape(-1, shapes.shape[1])


@pytest.mark.parametrize("relief", [0.0, 0.05])
def test_rigid_sheet_is_recovered_exactly(relief):
    camera = _camera(60)[:, :2]
    W = _project(camera, _sheet(300, relief=relief))
    W = W + np.random.default_rng(2).normal(size=(W.shape[0], 1))  # image translations
    rotations = plane.plane_rotations(W)
    assert rotations.shape == (60, 2, 3)
    assert np.allclose(rotations @ np.swapaxes(rotations, 1, 2), np.eye(2), atol=1e-10)
    assert rotation_errors_deg(rotations, camera).max() < (1e-5 if relief == 0 else 1.0)


def test_the_side_of_the_plane_is_chosen_consistently_in_every_frame():
    """Candidates given in a random order per frame, and a random sign of their depth
    column: the path of least acceleration returns the camera itself or its mirror image
    (one global reflection), never a mix."""
    camera = _camera(80, seed=3)[:, :2]
    rng = np.random.default_rng(4)
    mirrored = camera @ D
    swap = rng.random(80) < 0.5
    candidates = np.stack([np.where(swap[:, None, None], mirrored, camera)] * 2, axis=1)
    candidates[:, 1] = np.where(swap[:, None, None], camera, mirrored)
    chosen = plane.sign_path(candidates)
    same = np.all(np.isclose(chosen, camera), axis=(1, 2))
    other = np.all(np.isclose(chosen, mirrored), axis=(1, 2))
    assert same.all() or other.all()


def test_least_change_would_bounce_where_least_acceleration_crosses():
    """A camera whose depth column passes close to zero (the sheet seen nearly face-on):
    the signs of least acceleration follow it through; checking that the test is not
    vacuous, the first-difference path picks the bounce there."""
    n_frames = 40
    t = np.linspace(-1.0, 1.0, n_frames) + 0.013  # no frame exactly face-on
    yaw = np.radians(30.0) * t
    camera = np.zeros((n_frames, 2, 3))
    camera[:, 0] = np.column_stack([np.cos(yaw), np.zeros(n_frames), np.sin(yaw)])
    camera[:, 1] = [0.0, 1.0, 0.0]
    candidates = np.stack([camera, camera @ D], axis=1)
    candidates[t < 0] = candidates[t < 0][:, ::-1]  # labels swap where the camera crosses
    chosen = plane.sign_path(candidates)
    assert rotation_errors_deg(chosen, camera).max() < 1e-6
    bounce = np.where((t < 0)[:, None, None], camera @ D, camera)  # depth column never crosses

    def change(path: np.ndarray, order: int) -> float:
        return float(np.sum(np.diff(path, n=order, axis=0) ** 2))

    assert change(bounce, 1) < change(camera, 1)
    assert change(camera, 2) < change(bounce, 2)


def test_groups_that_leave_the_plane_are_outvoted():
    """A rigid sheet of 600 points of which a quarter (one end) flaps out of the plane by
    up to 0.4: with 8 groups their weight falls far below the others' and the rotations
    are closer to the truth than the one-group fit's."""
    n_frames, n_points = 60, 600
    camera = _camera(n_frames, seed=5)[:, :2]
    sheet = _sheet(n_points, seed=5)
    shapes = np.broadcast_to(sheet, (n_frames, n_points, 3)).copy()
    flap = sheet[:, 0] > 0.35
    phase = np.linspace(0.0, 6.0 * np.pi, n_frames)[:, None]
    shapes[:, flap, 2] += 0.4 * (sheet[flap, 0] - 0.35) / 0.35 * np.sin(phase + 4 * sheet[flap, 1])
    W = _project(camera, shapes)
    labels = plane.group_labels(W, 8)
    weights, _, _ = plane.group_weights(W, labels)
    flapping = np.array([flap[labels == g].mean() > 0.5 for g in range(labels.max() + 1)])
    assert flapping.any() and (~flapping).any()
    assert weights[flapping].max() < 0.2 * weights[~flapping].min()
    one = rotation_errors_deg(plane.plane_rotations(W, n_groups=1), camera).mean()
    eight = rotation_errors_deg(plane.plane_rotations(W, n_groups=8), camera).mean()
    assert eight < 0.5 * one


def test_one_group_is_the_plain_rank_two_fit():
    W = _project(_camera(30)[:, :2], _sheet(100, relief=0.1))
    labels = plane.group_labels(W, 1)
    assert np.array_equal(labels, np.zeros(100, dtype=np.int64))
    weights, basis, singular = plane.group_weights(W, labels)
    centred = W - W.mean(axis=1, keepdims=True)
    U, s, _ = np.linalg.svd(centred, full_matrices=False)
    assert np.allclose(weights, 1.0)
    assert np.allclose(singular, s[:2])
    assert np.allclose(np.abs(np.sum(basis * U[:, :2], axis=0)), 1.0)
    # More groups than the tracks allow fall back to fewer (8 tracks at least per group).
    assert plane.group_labels(W, 50).max() + 1 <= 100 // plane.MIN_GROUP_SIZE


def test_few_tracks_are_cut_into_fewer_groups_with_tracks_to_spare_on_a_turning_flag():
    """24 tracks of the turning flag (held-out seeds 301-306): the default 4 groups are cut
    to 24 // MIN_GROUP_SIZE = 3 so that each group has tracks to spare beyond the 3 a plane
    needs (mean rotation error 1.92 degrees); 4 groups of about 6 tracks (MIN_GROUP_SIZE 3 to
    6) give 2.52. With
    12 tracks the same bound leaves one group, and 4 groups of 3 did better there (2.81
    against 3.35 degrees at 1 % noise): the bound is measured, not optimal
    (benchmarks/results/rules/min_group_size/)."""
    errors = []
    for seed in range(301, 307):
        data = make_sequence("flag-turn", n_points=24, seed=seed)
        W = data.W - data.W.mean(axis=1, keepdims=True)
        errors.append(rotation_errors_deg(plane.plane_rotations(W), data.rotations).mean())
    assert np.mean(errors) < 2.2


def test_noise_bounds_the_weights_and_the_estimate_degrades_gently():
    camera = _camera(60, seed=6)[:, :2]
    W = _project(camera, _sheet(400, seed=6, relief=0.05))
    scale = np.abs(W).max()
    errors = []
    for level in (0.0, 0.01, 0.03, 0.055):
        noisy = W + np.random.default_rng(7).normal(scale=level * scale, size=W.shape)
        rotations = plane.plane_rotations(noisy, n_groups=4, noise_variance=(level * scale) ** 2)
        errors.append(rotation_errors_deg(rotations, camera).mean())
    assert errors[0] < 1.0
    assert all(e < 4.0 for e in errors)


def test_estimate_cameras_runs_the_plane_estimator_by_name():
    camera = _camera(40)[:, :2]
    W = _project(camera, _sheet(200, relief=0.05))
    W = W - W.mean(axis=1, keepdims=True)
    estimate = estimate_cameras(W, "plane")
    assert estimate.source == "plane"
    assert not estimate.refine
    assert rotation_errors_deg(estimate.rotations, camera).max() < 1.0
    grouped = estimate_cameras(W, "plane", n_groups=4)
    assert rotation_errors_deg(grouped.rotations, camera).max() < 1.0
    assert np.allclose(project_to_stiefel(grouped.rotations), grouped.rotations)
