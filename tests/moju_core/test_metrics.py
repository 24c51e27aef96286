"""Tests of moju_core.metrics: invariances, hand-computed values and input validation."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from moju_core.metrics import (
    align,
    center_frames,
    e3d,
    e3d_occluded,
    evaluate,
    rigid_approximation,
    rotation_error_deg,
    rotation_errors_deg,
)

MODES = ("procrustes", "global", "sign")
MIRROR_Z = np.diag([1.0, 1.0, -1.0])


def random_shapes(seed: int, n_frames: int = 6, n_points: int = 40) -> np.ndarray:
    """A non-rigid random sequence with a clear depth extent, (F, P, 3)."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(n_points, 3)) * np.array([1.0, 0.8, 0.5])
    return base + 0.2 * rng.normal(size=(n_frames, n_points, 3))


def random_orthogonal(seed: int, n: int, reflect: bool) -> np.ndarray:
    """n random 3x3 rotations, each turned into a reflection when asked, (n, 3, 3)."""
    rotations = Rotation.random(n, random_state=seed).as_matrix()
    return rotations @ MIRROR_Z if reflect else rotations


def in_plane(angle_deg: float) -> np.ndarray:
    """2x2 rotation of the image plane, i.e. a rotation about the camera's viewing axis."""
    a = np.radians(angle_deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


# --- e3d invariances ----------------------------------------------------------------------


@pytest.mark.parametrize("reflect", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_procrustes_forgives_per_frame_orthogonal_transforms(seed: int, reflect: bool) -> None:
    truth = random_shapes(seed)
    per_frame = random_orthogonal(seed + 10, truth.shape[0], reflect)
    estimate = truth @ per_frame
    assert e3d(estimate, truth, "procrustes") < 1e-12


@pytest.mark.parametrize("reflect", [False, True])
@pytest.mark.parametrize("mode", ["procrustes", "global"])
def test_global_transform_is_forgiven(mode: str, reflect: bool) -> None:
    truth = random_shapes(3)
    Q = random_orthogonal(4, 1, reflect)[0]
    assert e3d(truth @ Q, truth, mode) < 1e-12


@pytest.mark.parametrize("mode", MODES)
def test_per_frame_translation_is_forgiven(mode: str) -> None:
    truth = random_shapes(5)
    shifts = np.random.default_rng(6).normal(scale=10.0, size=(truth.shape[0], 1, 3))
    assert e3d(truth + shifts, truth, mode) < 1e-12
    assert e3d(truth, truth + shifts, mode) < 1e-12


def test_sign_mode_forgives_depth_mirror_once() -> None:
    truth = random_shapes(7)
    assert e3d(truth @ MIRROR_Z, truth, "sign") < 1e-12
    assert e3d(truth, truth, "sign") < 1e-12
    # Mirroring only half of the frames cannot be undone by one sign for the whole sequence.
    half = truth.copy()
    half[::2] = half[::2] @ MIRROR_Z
    assert e3d(half, truth, "sign") > 0.1


def test_sign_mode_does_not_forgive_a_rotation() -> None:
    truth = random_shapes(8)
    Q = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    assert e3d(truth @ Q, truth, "sign") > 0.1


# --- e3d hand-computed values --------------------------------------------------------------


@pytest.mark.parametrize("mode", MODES)
def test_per_frame_scaling_gives_the_scale_error(mode: str) -> None:
    # S_est^f = (1 + a_f) S_gt^f: the best orthogonal transform is the identity (the
    # cross-covariance (1 + a_f) S^T S is symmetric positive definite), so the relative error
    # of frame f is exactly |a_f| and e3D is their mean.
    truth = random_shapes(9, n_frames=4)
    factors = np.array([0.1, -0.05, 0.2, 0.0])
    estimate = truth * (1.0 + factors)[:, None, None]
    assert_allclose(e3d(estimate, truth, mode), np.abs(factors).mean(), rtol=1e-12)


def test_sign_mode_value_of_an_additive_perturbation() -> None:
    truth = center_frames(random_shapes(11, n_frames=3, n_points=30))
    rng = np.random.default_rng(12)
    perturbation = 0.05 * rng.normal(size=truth.shape)
    perturbation -= perturbation.mean(axis=1, keepdims=True)
    expected = np.mean(
        [np.sqrt(np.sum(perturbation[f] ** 2) / np.sum(truth[f] ** 2)) for f in range(3)]
    )
    assert_allclose(e3d(truth + perturbation, truth, "sign"), expected, rtol=1e-12)
    assert expected > 0.01


def test_global_mode_charges_opposite_per_frame_rotations() -> None:
    # Octahedron vertices +-e_i: S^T S = 2 I. Frames rotated by +theta and -theta about z:
    # sum_f R_f^T is symmetric positive definite, so the best global Q is the identity and
    # each frame's error is ||R - I||_F / sqrt(3) = 2 sqrt(2) sin(theta / 2) / sqrt(3).
    octahedron = np.vstack([np.eye(3), -np.eye(3)])
    theta = 20.0
    rotations = Rotation.from_euler("z", [[theta], [-theta]], degrees=True).as_matrix()
    truth = np.stack([octahedron, octahedron])
    estimate = truth @ rotations
    expected = 2.0 * np.sqrt(2.0) * np.sin(np.radians(theta) / 2.0) / np.sqrt(3.0)
    assert_allclose(e3d(estimate, truth, "global"), expected, rtol=1e-12)
    assert e3d(estimate, truth, "procrustes") < 1e-12


def test_align_returns_centred_aligned_estimate() -> None:
    truth = random_shapes(13)
    Q = random_orthogonal(14, 1, True)[0]
    estimate = truth @ Q + 3.0
    for mode in ("procrustes", "global"):
        aligned = align(estimate, truth, mode)
        assert_allclose(aligned, center_frames(truth), atol=1e-12)


def test_center_frames() -> None:
    shapes = random_shapes(15) + 5.0
    centred = center_frames(shapes)
    assert_allclose(centred.mean(axis=1), 0.0, atol=1e-12)
    assert_allclose(
        centred - shapes, np.broadcast_to(-shapes.mean(axis=1, keepdims=True), shapes.shape)
    )


# --- rigid approximation -------------------------------------------------------------------


def test_rigid_approximation_of_a_rigid_sequence_is_exact() -> None:
    base = random_shapes(16, n_frames=1)[0]
    per_frame = random_orthogonal(17, 5, False)
    rigid_truth = base @ per_frame + np.arange(5.0)[:, None, None]
    assert e3d(rigid_approximation(rigid_truth), rigid_truth) < 1e-12


def test_rigid_approximation_error_grows_with_deformation() -> None:
    rng = np.random.default_rng(18)
    base = rng.normal(size=(50, 3))
    motion = rng.normal(size=(6, 50, 3))
    errors = []
    for amplitude in (0.05, 0.2, 0.5):
        truth = base + amplitude * motion
        errors.append(e3d(rigid_approximation(truth), truth))
    assert 0.0 < errors[0] < errors[1] < errors[2]


# --- rotation error ------------------------------------------------------------------------


@pytest.mark.parametrize("reflect", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_rotation_error_forgives_a_global_orthogonal_transform(seed: int, reflect: bool) -> None:
    R_true = Rotation.random(8, random_state=seed).as_matrix()[:, :2, :]
    Q = random_orthogonal(seed + 20, 1, reflect)[0]
    errors = rotation_errors_deg(R_true @ Q, R_true)
    assert errors.shape == (8,)
    assert np.max(errors) < 1e-9
    assert rotation_error_deg(R_true @ Q, R_true) < 1e-9


def test_rotation_error_of_opposite_in_plane_rotations_is_exact() -> None:
    # Each true rotation appears twice, perturbed by +10 and -10 degrees about the viewing
    # axis. The cross-covariance sum_f R_true_f^T G_f R_true_f then has cancelling
    # antisymmetric parts and a positive definite symmetric part, so the global Q is the
    # identity and every frame is off by exactly 10 degrees.
    R_true = np.repeat(Rotation.random(4, random_state=30).as_matrix()[:, :2, :], 2, axis=0)
    perturbations = np.stack([in_plane(10.0), in_plane(-10.0)] * 4)
    errors = rotation_errors_deg(perturbations @ R_true, R_true)
    assert_allclose(errors, 10.0, atol=1e-9)


def test_rotation_error_of_a_common_in_plane_rotation_is_about_ten_degrees() -> None:
    # Diverse viewpoints leave little for the global alignment to absorb.
    R_true = Rotation.random(30, random_state=31).as_matrix()[:, :2, :]
    error = rotation_error_deg(in_plane(10.0) @ R_true, R_true)
    assert 9.0 < error < 10.5


def test_rotation_error_ignores_row_scale() -> None:
    # Estimates from factorisation are only approximately orthonormal; scale is not an error.
    R_true = Rotation.random(5, random_state=32).as_matrix()[:, :2, :]
    assert rotation_error_deg(1.7 * R_true, R_true) < 1e-9


# --- evaluate and validation ---------------------------------------------------------------


def test_evaluate_reports_all_measures() -> None:
    truth = random_shapes(40, n_frames=5)
    estimate = truth * 1.1
    R_true = Rotation.random(5, random_state=41).as_matrix()[:, :2, :]
    scores = evaluate(estimate, truth)
    assert set(scores) == {"e3d_procrustes", "e3d_global", "e3d_sign"}
    for value in scores.values():
        assert_allclose(value, 0.1, rtol=1e-12)
    with_rotations = evaluate(estimate, truth, R_true, R_true)
    assert with_rotations["rotation_error_deg"] < 1e-9
    with pytest.raises(ValueError, match="both"):
        evaluate(estimate, truth, R_est=R_true)


def test_mismatched_shapes_are_reported() -> None:
    truth = random_shapes(50, n_frames=3, n_points=10)
    with pytest.raises(ValueError, match=r"\(3, 9, 3\).*\(3, 10, 3\)"):
        e3d(truth[:, :9], truth)
    with pytest.raises(ValueError, match=r"\(3, 10, 2\)"):
        e3d(truth[..., :2], truth[..., :2])
    with pytest.raises(ValueError, match="mode"):
        align(truth, truth, "similarity")  # type: ignore[arg-type]
    R = Rotation.random(3, random_state=51).as_matrix()
    with pytest.raises(ValueError, match=r"\(3, 3, 3\)"):
        rotation_error_deg(R, R)
    with pytest.raises(ValueError, match=r"\(2, 2, 3\).*\(3, 2, 3\)"):
        rotation_error_deg(R[:2, :2], R[:, :2])


def test_degenerate_truth_frame_is_rejected() -> None:
    truth = random_shapes(52, n_frames=2, n_points=10)
    truth[1] = 1.0
    with pytest.raises(ValueError, match="single point"):
        e3d(truth, truth)


# --- occluded entries -----------------------------------------------------------------------


def occluded_example() -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Truth, an estimate wrong only at frame 0's occluded points 2 and 3 (by +v and -v, so
    the frame's centroid stays), a visibility, and the hand-computed occluded and overall e3D."""
    truth = random_shapes(60, n_frames=3, n_points=10)
    visibility = np.ones((3, 10), dtype=bool)
    visibility[0, [2, 3]] = False  # wrong in the estimate
    visibility[1, 5] = False  # filled in exactly
    estimate = truth.copy()
    v = np.array([0.3, -0.2, 0.1])
    estimate[0, 2] += v
    estimate[0, 3] -= v
    centred = center_frames(truth)
    wrong = np.sqrt(2.0) * np.linalg.norm(v)
    occluded = (wrong / np.linalg.norm(centred[0, [2, 3]]) + 0.0) / 2  # frame 2 is skipped
    overall = (wrong / np.linalg.norm(centred[0])) / 3
    return truth, estimate, visibility, occluded, overall


def test_e3d_occluded_of_a_constructed_example() -> None:
    truth, estimate, visibility, occluded, overall = occluded_example()
    assert_allclose(e3d_occluded(estimate, truth, visibility, "sign"), occluded, rtol=1e-12)
    assert_allclose(e3d(estimate, truth, "sign"), overall, rtol=1e-12)
    # Errors at observed entries are not counted: frame 2 has no occluded point, frame 1's
    # observed points 0 and 1 move without moving the centroid.
    elsewhere = estimate.copy()
    elsewhere[2] *= 1.5
    elsewhere[1, 0] += [0.2, 0.0, 0.0]
    elsewhere[1, 1] -= [0.2, 0.0, 0.0]
    assert_allclose(e3d_occluded(elsewhere, truth, visibility, "sign"), occluded, rtol=1e-12)
    assert e3d(elsewhere, truth, "sign") > overall


@pytest.mark.parametrize("mode", MODES)
def test_e3d_occluded_forgives_what_the_alignment_forgives(mode: str) -> None:
    truth, _, visibility, _, _ = occluded_example()
    Q = random_orthogonal(61, 1, reflect=False)[0] if mode != "sign" else MIRROR_Z
    assert e3d_occluded(truth @ Q + 2.0, truth, visibility, mode) < 1e-12


def test_evaluate_reports_the_occluded_error_when_something_is_occluded() -> None:
    truth, estimate, visibility, occluded, overall = occluded_example()
    scores = evaluate(estimate, truth, visibility=visibility)
    assert set(scores) == {
        "e3d_procrustes", "e3d_global", "e3d_sign", "e3d_occluded_procrustes",
        "e3d_occluded_global", "e3d_occluded_sign", "observed_fraction",
    }  # fmt: skip
    assert_allclose(scores["e3d_occluded_sign"], occluded, rtol=1e-12)
    assert_allclose(scores["e3d_sign"], overall, rtol=1e-12)
    assert scores["observed_fraction"] == pytest.approx(27 / 30)
    for mode in MODES:
        assert scores[f"e3d_occluded_{mode}"] == e3d_occluded(estimate, truth, visibility, mode)
        assert scores[f"e3d_{mode}"] == e3d(estimate, truth, mode)
    complete = evaluate(estimate, truth, visibility=np.ones_like(visibility))
    assert complete == evaluate(estimate, truth)


def test_e3d_occluded_refuses_unusable_masks() -> None:
    truth, estimate, visibility, _, _ = occluded_example()
    with pytest.raises(ValueError, match="nothing is occluded"):
        e3d_occluded(estimate, truth, np.ones_like(visibility))
    with pytest.raises(ValueError, match=r"shape \(F, P\) = \(3, 10\)"):
        e3d_occluded(estimate, truth, visibility[:, :9])
    with pytest.raises(ValueError, match="bool"):
        e3d_occluded(estimate, truth, visibility.astype(int))
