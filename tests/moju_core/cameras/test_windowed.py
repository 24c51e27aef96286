"""Rotations from chained rigid factorisations of short windows, the rigidity measure, and the
blocks of W W^T near the diagonal that both work on."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from moju_core.cameras import windowed
from moju_core.cameras.intersection import intersection_rotations
from moju_core.cameras.refinement import project_to_stiefel
from moju_core.cameras.rigid import rigid_from_factor, rigid_rotations
from moju_core.cameras.windowed import RowGram
from moju_core.datasets import make_sequence
from moju_core.metrics import rotation_error_deg
from moju_core.preprocessing import normalise


@pytest.mark.parametrize(("n_frames", "reach"), [(40, 6), (40, 30), (9, 9)])
def test_window_blocks_are_the_blocks_of_the_full_product(n_frames, reach):
    W = np.random.default_rng(n_frames).standard_normal((2 * n_frames, 7))
    gram = RowGram(W, reach)
    assert (gram.dense is None) == (reach < n_frames // 2)
    full = W @ W.T
    for length in (1, 3, reach):
        blocks = gram.windows(length)
        assert blocks.shape == (n_frames - length + 1, 2 * length, 2 * length)
        for start in (0, n_frames - length):
            rows = slice(2 * start, 2 * (start + length))
            assert_allclose(blocks[start], full[rows, rows], atol=1e-12)
    assert gram.total == pytest.approx(np.trace(full))
    with pytest.raises(ValueError, match="window length"):
        gram.windows(reach + 1)


def _gram(W: np.ndarray) -> RowGram:
    """Every block of W W^T (windows up to the whole sequence)."""
    return RowGram(W, W.shape[0] // 2)


def _turning_camera(n_frames: int, seed: int = 0) -> np.ndarray:
    """Smooth rotations about all three axes (+-60 degrees of yaw), (F, 2, 3)."""
    t = np.linspace(0.0, 1.0, n_frames)
    rng = np.random.default_rng(seed)
    amplitudes = np.radians([20.0, 60.0, 5.0])
    frequencies, phases = rng.uniform(1.0, 3.0, 3), rng.uniform(0.0, 6.0, 3)
    rotations = np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy()
    for axis in range(3):
        angle = amplitudes[axis] * np.sin(2 * np.pi * frequencies[axis] * t + phases[axis])
        i, j = [k for k in range(3) if k != axis]
        turn = np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy()
        turn[:, i, i] = turn[:, j, j] = np.cos(angle)
        turn[:, i, j], turn[:, j, i] = -np.sin(angle), np.sin(angle)
        rotations = rotations @ turn
    return rotations[:, :2]


def _rigid_tracks(n_frames: int, n_points: int = 200, noise: float = 0.0):
    rotations = _turning_camera(n_frames)
    rng = np.random.default_rng(1)
    shape = rng.standard_normal((3, n_points)) * np.array([[1.0], [0.8], [0.4]])
    W = np.einsum("fij,jp->fip", rotations, shape).reshape(2 * n_frames, n_points)
    W = W + noise * rng.standard_normal(W.shape)
    W -= W.mean(axis=1, keepdims=True)
    return W, rotations


@pytest.mark.parametrize("window", [4, 8, 30])
def test_a_rigid_object_gives_exact_rotations_for_any_window(window):
    W, truth = _rigid_tracks(30)
    estimate = windowed.windowed_rotations(_gram(W), window)
    assert_allclose(
        estimate @ estimate.transpose(0, 2, 1), np.broadcast_to(np.eye(2), (30, 2, 2)), atol=1e-12
    )
    assert rotation_error_deg(estimate, truth) < 1e-6


def test_window_factorisations_match_the_single_factor_upgrade():
    rng = np.random.default_rng(2)
    factors = rng.standard_normal((5, 12, 3))
    stacked = rigid_from_factor(factors)
    for factor, rotations in zip(factors, stacked, strict=True):
        assert_allclose(rotations, rigid_from_factor(factor), atol=1e-12)


def test_rigidity_is_zero_for_the_true_rotations_of_a_rigid_object_and_grows_with_errors():
    W, truth = _rigid_tracks(20)
    gram = _gram(W)
    assert windowed.short_time_rigidity(gram, truth) < 1e-12
    rng = np.random.default_rng(3)
    perturbed = project_to_stiefel(truth + 0.05 * rng.standard_normal(truth.shape))
    assert windowed.short_time_rigidity(gram, perturbed) > 1e-4
    # A global rotation and reflection of all frames changes nothing.
    turn = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    assert windowed.short_time_rigidity(gram, truth @ turn) < 1e-12


def test_noise_adds_half_its_variance_to_the_rigidity():
    noise = 0.02
    W, truth = _rigid_tracks(40, n_points=2000, noise=noise)
    measured = windowed.short_time_rigidity(_gram(W), truth)
    expected = 0.5 * noise**2 / np.mean(W**2)  # 3 unknowns per point for 6 equations
    assert measured == pytest.approx(expected, rel=0.1)


def test_the_best_window_is_the_most_rigid_one():
    data = make_sequence("paper", n_points=1000)
    centred, _ = normalise(data.W)
    gram = RowGram(centred, max(windowed.WINDOW_LENGTHS))
    rigid = rigid_rotations(centred)
    rotations, window, rigidity = windowed.best_windowed_rotations(gram, rigid)
    candidates = [w for w in windowed.WINDOW_LENGTHS if w < data.n_frames]
    others = [windowed.windowed_rotations(gram, length) for length in candidates]
    for other in [*others, rigid]:
        assert rigidity <= windowed.short_time_rigidity(gram, other) + 1e-15
    assert window < data.n_frames  # the rolling sheet is far from rigid over all frames
    assert_allclose(rotations, windowed.windowed_rotations(gram, window))


def test_on_a_rolling_sheet_the_windows_beat_the_shape_bases():
    # The sheet rolls up: no few shape bases describe it, and the intersection method is far
    # off (measured 61-80 degrees); over a few frames it is nearly rigid (12-25 degrees, the
    # error being mostly the sheet's own turning, which the shapes absorb).
    data = make_sequence("paper", n_points=1000)
    centred, _ = normalise(data.W)
    gram = RowGram(centred, max(windowed.WINDOW_LENGTHS))
    chained, _, windowed_rigidity = windowed.best_windowed_rotations(gram, rigid_rotations(centred))
    with pytest.warns(RuntimeWarning, match="no corrective triple fits W"):
        intersection = intersection_rotations(centred, 3)
    assert rotation_error_deg(chained, data.rotations) < 30.0
    assert rotation_error_deg(intersection, data.rotations) > 45.0
    intersection_rigidity = windowed.short_time_rigidity(gram, intersection)
    assert windowed_rigidity < 0.1 * intersection_rigidity


def test_too_long_or_short_windows_are_refused():
    W, _ = _rigid_tracks(10)
    for window in (2, 11):
        with pytest.raises(ValueError, match="window must be between 3"):
            windowed.windowed_rotations(_gram(W), window)


def test_long_sequences_give_the_same_rotations_from_the_diagonals_alone():
    W, truth = _rigid_tracks(150, n_points=20, noise=0.01)
    banded = RowGram(W, max(windowed.WINDOW_LENGTHS))
    assert banded.dense is None  # 150 frames: only the diagonals within 50 frames
    for window in (6, 50):
        assert_allclose(
            windowed.windowed_rotations(banded, window),
            windowed.windowed_rotations(_gram(W), window),
            atol=1e-9,
        )
