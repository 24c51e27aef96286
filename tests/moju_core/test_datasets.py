"""Tests of moju_core.datasets: shapes, determinism, projection model, camera paths, the
low-rank and non-rigidity claims, and the noise protocol."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from moju_core.datasets import (
    BODY_SEQUENCE_NAMES,
    HARD_SEQUENCE_NAMES,
    SEQUENCE_NAMES,
    Sequence,
    add_noise,
    body_sequence,
    bumps_sequence,
    cloth_sequence,
    face_sequence,
    flag_sequence,
    make_sequence,
    paper_sequence,
    roll_sequence,
)
from moju_core.datasets.body import JOINTS, marker_bones
from moju_core.datasets.surfaces import parameter_grid
from moju_core.metrics import e3d, rigid_approximation

SMALL = 600  # points per sequence where the full density is not what is being tested
ALL_NAMES = SEQUENCE_NAMES + HARD_SEQUENCE_NAMES


def yaw_pitch_deg(rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yaw and pitch of R = Rz(roll) Rx(pitch) Ry(yaw), read off the viewing direction.

    The third row of R is unaffected by the roll and equals
    [-cos(pitch) sin(yaw), sin(pitch), cos(pitch) cos(yaw)].
    """
    view = np.cross(rotations[:, 0], rotations[:, 1])
    return np.degrees(np.arctan2(-view[:, 0], view[:, 2])), np.degrees(np.arcsin(view[:, 1]))


def turning_points(values: np.ndarray) -> int:
    """Number of interior local extrema of a sampled signal."""
    slopes = np.sign(np.diff(values))
    return int(np.count_nonzero(slopes[1:] != slopes[:-1]))


# --- structure -----------------------------------------------------------------------------


@pytest.mark.parametrize("name", ALL_NAMES)
def test_arrays_have_documented_shapes_and_dtypes(name: str) -> None:
    sequence = make_sequence(name, n_points=SMALL)
    F, P = sequence.n_frames, sequence.n_points
    assert P == SMALL
    assert sequence.name == name
    assert sequence.W.shape == (2 * F, P) and sequence.W.dtype == np.float64
    assert sequence.rotations.shape == (F, 2, 3) and sequence.rotations.dtype == np.float64
    assert sequence.shapes.shape == (F, P, 3) and sequence.shapes.dtype == np.float64
    assert sequence.translations.shape == (F, 2)
    assert sequence.colors.shape == (P, 3) and sequence.colors.dtype == np.uint8
    assert sequence.faces is not None and sequence.faces.dtype == np.int64
    assert sequence.faces.shape[1] == 3 and sequence.faces.shape[0] > P  # ~2 per point
    assert np.all(np.isfinite(sequence.W))
    assert sequence.to_arrays().keys() == {"W", "R", "gt", "faces", "colors"}


@pytest.mark.parametrize(
    ("name", "n_frames", "n_points"),
    [
        ("face1", 10, 28_880),
        ("face2", 10, 28_880),
        ("face3", 99, 28_880),
        ("face4", 99, 28_880),
        ("paper", 60, 10_000),
        ("cloth", 60, 10_000),
        *((name, 60, 10_000) for name in HARD_SEQUENCE_NAMES),
    ],
)
def test_benchmark_default_sizes(name: str, n_frames: int, n_points: int) -> None:
    sequence = make_sequence(name)
    assert (sequence.n_frames, sequence.n_points) == (n_frames, n_points)


def test_sizes_can_be_overridden() -> None:
    sequence = make_sequence("face3", n_frames=17, n_points=123)
    assert (sequence.n_frames, sequence.n_points) == (17, 123)
    sequence = make_sequence("cloth", n_frames=5)
    assert (sequence.n_frames, sequence.n_points) == (5, 10_000)


@pytest.mark.parametrize(
    "generator",
    [face_sequence, paper_sequence, cloth_sequence, flag_sequence, roll_sequence, bumps_sequence],
)
@pytest.mark.parametrize("n_points", [4, 5, 37, 101])
def test_small_point_counts_are_honoured_with_a_valid_mesh(generator, n_points: int) -> None:
    sequence = generator(n_frames=4, n_points=n_points)
    assert sequence.n_points == n_points
    faces = sequence.faces
    assert faces is not None and faces.shape[0] >= 1
    assert faces.min() >= 0 and faces.max() < n_points
    # Three distinct corners per triangle, every triangle listed once.
    assert np.all((faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]))
    assert np.all(faces[:, 0] != faces[:, 2])
    assert np.unique(np.sort(faces, axis=1), axis=0).shape[0] == faces.shape[0]
    # Triangles have non-zero area in 3D (the grid is not collinear even at 4 points).
    corners = sequence.shapes[0][faces]
    areas = np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    assert np.all(areas > 1e-6)


def test_invalid_requests_are_rejected() -> None:
    with pytest.raises(ValueError, match="n_points"):
        face_sequence(n_points=3)
    with pytest.raises(ValueError, match="n_frames"):
        paper_sequence(n_frames=1)
    with pytest.raises(ValueError, match="rotation_frequency"):
        face_sequence(n_points=50, rotation_frequency="medium")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="face1"):
        make_sequence("t-shirt")
    with pytest.raises(ValueError, match="flag-osc"):
        make_sequence("flag")
    with pytest.raises(ValueError, match="camera"):
        flag_sequence(n_points=50, camera="handheld")  # type: ignore[arg-type]
    sequence = make_sequence("face1", n_points=20)
    with pytest.raises(ValueError, match=r"W must have shape \(20, 20\)"):
        Sequence(
            "broken",
            sequence.W[:-1],
            sequence.rotations,
            sequence.shapes,
            sequence.translations,
            sequence.faces,
            sequence.colors,
        )


# --- determinism ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ALL_NAMES)
def test_same_seed_same_arrays_other_seed_other_arrays(name: str) -> None:
    first = make_sequence(name, n_points=SMALL, seed=3)
    again = make_sequence(name, n_points=SMALL, seed=3)
    other = make_sequence(name, n_points=SMALL, seed=4)
    for field in ("W", "rotations", "shapes", "translations", "faces", "colors"):
        assert_array_equal(getattr(first, field), getattr(again, field))
    assert np.max(np.abs(first.shapes - other.shapes)) > 1e-3
    assert np.max(np.abs(first.W - other.W)) > 1e-3


# --- projection model and camera ----------------------------------------------------------


@pytest.mark.parametrize("name", ALL_NAMES)
def test_tracks_are_orthographic_projections_plus_translation(name: str) -> None:
    sequence = make_sequence(name, n_points=SMALL)
    F = sequence.n_frames
    for f in range(F):
        projected = sequence.rotations[f] @ sequence.shapes[f].T
        projected += sequence.translations[f][:, None]
        assert_allclose(sequence.W[2 * f : 2 * f + 2], projected, rtol=0, atol=1e-12)
    # Translations really are there (their removal gets exercised) and shapes are centred.
    assert np.max(np.abs(sequence.translations)) > 1e-2
    assert_allclose(sequence.shapes.mean(axis=1), 0.0, atol=1e-12)
    assert_allclose(sequence.W.mean(axis=1), sequence.translations.ravel(), atol=1e-12)


@pytest.mark.parametrize("name", ALL_NAMES)
def test_rotation_rows_are_orthonormal(name: str) -> None:
    rotations = make_sequence(name, n_points=SMALL).rotations
    gram = rotations @ rotations.transpose(0, 2, 1)
    assert_allclose(gram, np.broadcast_to(np.eye(2), gram.shape), atol=1e-12)


@pytest.mark.parametrize(
    ("name", "range_deg"),
    [("face1", 30), ("face2", 90), ("face3", 30), ("face4", 30), ("paper", 60), ("cloth", 60)],
)
def test_yaw_spans_the_requested_range_and_motion_is_not_single_axis(
    name: str, range_deg: float
) -> None:
    rotations = make_sequence(name, n_points=SMALL).rotations
    yaw, pitch = yaw_pitch_deg(rotations)
    assert abs(yaw.max() - range_deg) < 0.5
    assert abs(yaw.min() + range_deg) < 0.5
    # Pitch of about a third of the range, and varying: rotation is not about one axis.
    assert np.max(np.abs(pitch)) <= range_deg / 3.0 + 1e-9
    assert np.ptp(pitch) > range_deg / 6.0


def test_rotation_frequency_changes_the_number_of_yaw_cycles() -> None:
    yaw_high, _ = yaw_pitch_deg(make_sequence("face3", n_points=SMALL).rotations)
    yaw_low, _ = yaw_pitch_deg(make_sequence("face4", n_points=SMALL).rotations)
    assert turning_points(yaw_high) == 5  # 3 cycles starting at -range: 5 interior extrema
    assert turning_points(yaw_low) == 1  # 1 cycle: up to +range and back
    # The sheets sweep about three times too (2.95 cycles in 60 frames).
    for name in ("paper", "cloth"):
        yaw, _ = yaw_pitch_deg(make_sequence(name, n_points=SMALL).rotations)
        assert turning_points(yaw) == 5
    # Ten frames cannot show a cycle; both frequencies become one monotonic sweep.
    for frequency in ("low", "high"):
        yaw, _ = yaw_pitch_deg(
            face_sequence(n_frames=10, n_points=50, rotation_frequency=frequency).rotations
        )
        assert turning_points(yaw) == 0
        assert_allclose([yaw[0], yaw[-1]], [-30.0, 30.0], atol=1e-9)


# --- deformation claims --------------------------------------------------------------------


def test_face_shapes_are_approximately_but_not_exactly_low_rank() -> None:
    sequence = make_sequence("face3")
    # S# (F x 3P): row f is [X_f, Y_f, Z_f].
    shape_matrix = sequence.shapes.transpose(0, 2, 1).reshape(sequence.n_frames, -1)
    energy = np.linalg.svd(shape_matrix, compute_uv=False) ** 2
    cumulative = np.cumsum(energy) / energy.sum()
    assert cumulative[5] > 0.99
    assert cumulative[2] < 0.9999


@pytest.mark.parametrize("name", ["paper", "cloth"])
def test_paper_and_cloth_are_far_from_rigid(name: str) -> None:
    sequence = make_sequence(name)
    rigid_estimate = rigid_approximation(sequence.shapes)
    assert e3d(rigid_estimate, sequence.shapes, "procrustes") > 0.15


@pytest.mark.parametrize("name", ["face1", "face2", "face3", "face4"])
def test_faces_are_mildly_non_rigid(name: str) -> None:
    sequence = make_sequence(name, n_points=4000)
    error = e3d(rigid_approximation(sequence.shapes), sequence.shapes, "procrustes")
    assert 0.03 < error < 0.15


def test_paper_bends_without_stretching() -> None:
    sequence = make_sequence("paper", n_points=2000)
    faces = sequence.faces
    assert faces is not None
    for first, second in ((0, 1), (1, 2), (2, 0)):
        edges = sequence.shapes[:, faces[:, first]] - sequence.shapes[:, faces[:, second]]
        lengths = np.linalg.norm(edges, axis=-1)
        # Chords of a curved sheet are a little shorter than the arcs they span; grid edges
        # of ~0.04 on radii above 0.25 lose less than 0.2 %.
        assert np.max(np.abs(lengths / lengths[0] - 1.0)) < 2e-3
    # ...while it does roll up: the last frame's depth extent is a sizable fraction of the
    # sheet's 2-unit length, against a flat first frame.
    assert np.ptp(sequence.shapes[0, :, 2]) < 1e-9
    assert np.ptp(sequence.shapes[-1, :, 2]) > 0.4


# --- hard sequences ------------------------------------------------------------------------

HARD_POINTS = 2_000


def full_rotations(rotations: np.ndarray) -> np.ndarray:
    """(F, 2, 3) camera rows completed to (F, 3, 3) rotations."""
    third = np.cross(rotations[:, 0], rotations[:, 1])
    return np.concatenate([rotations, third[:, None, :]], axis=1)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("name", HARD_SEQUENCE_NAMES)
def test_hard_sequences_are_far_from_any_rigid_shape(name: str, seed: int) -> None:
    sequence = make_sequence(name, n_points=HARD_POINTS, seed=seed)
    error = e3d(rigid_approximation(sequence.shapes), sequence.shapes, "procrustes")
    assert error >= 0.12


def test_hard_seeds_share_the_deformation_across_cameras_not_across_seeds() -> None:
    oscillating = make_sequence("roll-osc", n_points=SMALL, seed=1)
    turntable = make_sequence("roll-turn", n_points=SMALL, seed=1)
    assert_array_equal(oscillating.shapes, turntable.shapes)
    assert np.max(np.abs(oscillating.rotations - turntable.rotations)) > 0.1
    other_seed = make_sequence("roll-osc", n_points=SMALL, seed=2)
    assert np.max(np.abs(other_seed.rotations - oscillating.rotations)) > 0.1


@pytest.mark.parametrize("deformation", ["flag", "roll", "bumps"])
def test_oscillating_camera_swings_30_to_45_degrees_with_a_20_to_40_frame_period(
    deformation: str,
) -> None:
    for seed in range(3):
        rotations = make_sequence(f"{deformation}-osc", n_points=SMALL, seed=seed).rotations
        yaw, pitch = yaw_pitch_deg(rotations)
        assert 30.0 <= np.max(np.abs(yaw)) <= 45.0
        # 60 frames at a period of 20-40 frames: 1.5 to 3 cycles, 3 to 6 extrema.
        assert 3 <= turning_points(yaw) <= 6
        assert np.ptp(pitch) > 10.0  # not about a single axis


@pytest.mark.parametrize("deformation", ["flag", "roll", "bumps"])
def test_turntable_turns_2_to_5_degrees_per_frame(deformation: str) -> None:
    rotations = full_rotations(make_sequence(f"{deformation}-turn", n_points=SMALL).rotations)
    relative = rotations[1:] @ rotations[:-1].transpose(0, 2, 1)
    cosines = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    steps = np.degrees(np.arccos(cosines))
    assert np.all((steps >= 2.0) & (steps <= 5.0))
    # Over the sequence the view turns far: the first and last views differ by > 90 degrees
    # about the sheet's normal.
    view_first, view_last = rotations[0, 0], rotations[-1, 0]
    assert np.degrees(np.arccos(np.clip(view_first @ view_last, -1, 1))) > 90.0


def test_flag_is_pinned_along_one_edge_with_waves_shorter_than_it() -> None:
    sequence = make_sequence("flag-osc", n_points=HARD_POINTS, seed=3)
    u, v, _ = parameter_grid(HARD_POINTS, aspect=1.4)
    moved = sequence.shapes - sequence.shapes[:1]
    # Shapes are centred per frame, so a pinned point moves only with the centroid: the whole
    # pinned edge shifts by one common vector, while the free edge spreads out.
    for edge, (low, high) in ((u == 0.0, (0.0, 1e-12)), (u == 1.0, (0.2, np.inf))):
        spread = np.abs(moved[:, edge] - moved[:, edge].mean(axis=1, keepdims=True)).max()
        assert low <= spread <= high
    # Along the middle row the height has at least two extrema in every frame: at least one
    # wavelength fits into the flag.
    middle = np.isclose(v, np.unique(v)[np.unique(v).size // 2])
    order = np.argsort(u[middle])
    for shape in sequence.shapes:
        assert turning_points(shape[middle][order, 2]) >= 2


def test_roll_turns_more_than_once_without_stretching() -> None:
    sequence = make_sequence("roll-osc", n_points=HARD_POINTS, seed=3)
    u, v, faces = parameter_grid(HARD_POINTS, aspect=1.4)
    rest = np.stack([2.0 * u, 2.0 / 1.4 * v, np.zeros_like(u)], axis=1)
    rest_lengths = np.linalg.norm(rest[faces[:, 0]] - rest[faces[:, 1]], axis=1)
    lengths = np.linalg.norm(
        sequence.shapes[:, faces[:, 0]] - sequence.shapes[:, faces[:, 1]], axis=-1
    )
    # Chords on the tightest turns (radius ~0.1, edges ~0.04) are < 1 % shorter than arcs.
    assert np.max(np.abs(lengths / rest_lengths - 1.0)) < 1e-2
    assert np.ptp(sequence.shapes[0, :, 2]) < 1e-9  # starts flat
    # The last frame's cross-section turns by more than a full circle.
    edge = v == 0.0
    section = sequence.shapes[-1, edge][np.argsort(u[edge])]
    steps = np.diff(section, axis=0)
    turn = np.ptp(np.unwrap(np.arctan2(steps[:, 2], steps[:, 0])))
    assert np.degrees(turn) > 400.0


def test_bumps_rise_while_their_neighbours_sink() -> None:
    sequence = make_sequence("bumps-osc", n_points=HARD_POINTS, seed=3)
    heights = sequence.shapes[:, :, 2]
    # In every frame some bump stands up and another is a dent (out of phase), and the
    # height of every point changes over the sequence.
    assert np.all(heights.max(axis=1) > 0.1)
    assert np.all(heights.min(axis=1) < -0.1)
    first_half = heights[: sequence.n_frames // 2]
    assert np.ptp(first_half, axis=0).max() > 0.3


def test_hard_noise_variant_keeps_the_ground_truth() -> None:
    clean = make_sequence("bumps-turn", n_points=SMALL, seed=1)
    noisy = make_sequence("bumps-turn", n_points=SMALL, seed=1, noise=0.03)
    assert noisy.noise == 0.03
    assert_array_equal(noisy.shapes, clean.shapes)
    residual = noisy.W - clean.W
    assert abs(np.std(residual) / (0.03 * np.max(np.abs(clean.W))) - 1.0) < 0.05


# --- noise ---------------------------------------------------------------------------------


@pytest.mark.parametrize("level", [0.01, 0.055])
def test_add_noise_has_the_protocol_standard_deviation(level: float) -> None:
    W = make_sequence("face1").W
    original = W.copy()
    noisy = add_noise(W, level, seed=7)
    assert_array_equal(W, original)  # input untouched
    expected = level * np.max(np.abs(W))
    measured = np.std(noisy - W)
    assert abs(measured / expected - 1.0) < 0.05
    assert abs(np.mean(noisy - W)) < 0.05 * expected


def test_add_noise_edge_cases() -> None:
    W = make_sequence("face1", n_points=30).W
    zero = add_noise(W, 0.0)
    assert_array_equal(zero, W)
    assert zero is not W
    assert_array_equal(add_noise(W, 0.02, seed=1), add_noise(W, 0.02, seed=1))
    with pytest.raises(ValueError, match="noise"):
        add_noise(W, -0.01)


def test_make_sequence_with_noise_keeps_the_ground_truth() -> None:
    clean = make_sequence("cloth", n_points=SMALL, seed=2)
    noisy = make_sequence("cloth", n_points=SMALL, seed=2, noise=0.03)
    assert noisy.noise == 0.03 and clean.noise == 0.0
    assert_array_equal(noisy.shapes, clean.shapes)
    assert_array_equal(noisy.rotations, clean.rotations)
    residual = noisy.W - clean.W
    assert abs(np.std(residual) / (0.03 * np.max(np.abs(clean.W))) - 1.0) < 0.05


# --- speed ---------------------------------------------------------------------------------


# --- articulated body ---------------------------------------------------------------------


@pytest.mark.parametrize("name", BODY_SEQUENCE_NAMES)
def test_body_is_markers_projected_like_every_sequence(name: str) -> None:
    sequence = make_sequence(name)
    assert (sequence.n_frames, sequence.n_points, sequence.name) == (350, 41, name)
    assert sequence.faces is None and sequence.colors.dtype == np.uint8
    for f in (0, 100, 349):
        projected = sequence.rotations[f] @ sequence.shapes[f].T
        projected += sequence.translations[f][:, None]
        assert_allclose(sequence.W[2 * f : 2 * f + 2], projected, rtol=0, atol=1e-12)
    again = make_sequence(name)
    assert_array_equal(again.W, sequence.W)
    assert np.max(np.abs(make_sequence(name, seed=1).W - sequence.W)) > 1e-2


def test_body_markers_keep_their_place_on_their_bone_while_limbs_move() -> None:
    sequence = body_sequence(n_frames=200, n_points=64, seed=2)
    bones = marker_bones(64)
    distances = np.linalg.norm(sequence.shapes[:, :, None] - sequence.shapes[:, None], axis=-1)
    spread = np.ptp(distances, axis=0)  # (P, P): how much each distance changes
    same_bone = bones[:, None] == bones[None, :]
    assert np.max(spread[same_bone]) < 1e-12  # rigid on their bone
    # Markers of the two forearms move against each other by several centimetres (units ~m).
    forearms = [list(JOINTS).index(j) for j in ("left wrist", "right wrist")]
    left, right = (np.flatnonzero(bones == b) for b in forearms)
    assert np.min(spread[np.ix_(left, right)]) > 0.05


@pytest.mark.parametrize("seed", [0, 1])
def test_body_is_far_from_any_rigid_shape(seed: int) -> None:
    shapes = make_sequence("body-osc", seed=seed).shapes
    assert e3d(rigid_approximation(shapes), shapes) > 0.1


def test_body_cameras_oscillate_or_circle() -> None:
    for seed in range(2):
        osc = make_sequence("body-osc", seed=seed).rotations
        yaw, pitch = yaw_pitch_deg(osc)
        assert 29.0 <= np.max(np.abs(yaw)) <= 30.0 + 1e-9
        assert np.ptp(pitch) > 10.0
        circling = full_rotations(make_sequence("body-turn", seed=seed).rotations)
        relative = circling[1:] @ circling[:-1].transpose(0, 2, 1)
        cosines = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        assert_allclose(np.degrees(np.arccos(cosines)), 2.0, atol=0.1)
