"""Tests of moju_core.validation: every check accepts good input and explains bad input."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from moju_core.errors import MeasurementError
from moju_core.validation import (
    W_to_tracks,
    check_colors,
    check_dtype,
    check_faces,
    check_ground_truth,
    check_measurements,
    check_observations,
    check_rotations,
    tracks_to_W,
    with_missing,
)


def random_rotations(n_frames: int, seed: int = 0) -> np.ndarray:
    """(F, 2, 3) cameras: the first two rows of random orthogonal matrices."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(n_frames, 3, 3)))
    return q[:, :2, :]


# ---------------------------------------------------------------------------------------------
# check_measurements


def test_check_measurements_returns_contiguous_float64_and_keeps_values():
    W = np.arange(24, dtype=np.int32).reshape(4, 6)
    checked = check_measurements(W)
    assert checked.dtype == np.float64
    assert checked.flags.c_contiguous
    assert_array_equal(checked, W)


def test_check_measurements_does_not_copy_when_nothing_to_convert():
    W = np.random.default_rng(0).normal(size=(4, 5))
    assert check_measurements(W) is W


def test_check_measurements_copies_fortran_order_into_c_order():
    W = np.asfortranarray(np.random.default_rng(1).normal(size=(6, 5)))
    checked = check_measurements(W)
    assert checked.flags.c_contiguous
    assert checked is not W
    assert_array_equal(checked, W)


def test_check_measurements_accepts_nested_lists():
    checked = check_measurements([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]])
    assert checked.shape == (4, 3)


@pytest.mark.parametrize(
    ("W", "fragment"),
    [
        (np.ones((4, 3), dtype=bool), "booleans"),
        (np.ones((4, 3), dtype=complex), "complex"),
        (np.full((4, 3), "1.0"), "strings"),
        (np.array([[{}, {}, {}]] * 4, dtype=object), "Python objects"),
        (np.zeros((4, 3), dtype="datetime64[s]"), "dates"),
    ],
)
def test_check_measurements_rejects_non_real_dtypes(W, fragment):
    with pytest.raises(MeasurementError, match=fragment):
        check_measurements(W)


def test_check_measurements_rejects_ragged_lists():
    with pytest.raises(MeasurementError, match="not a rectangular array"):
        check_measurements([[1.0, 2.0, 3.0], [1.0, 2.0]])


@pytest.mark.parametrize("shape", [(8,), (2, 3, 4)])
def test_check_measurements_rejects_wrong_dimensions(shape):
    with pytest.raises(MeasurementError, match=r"shape \(2F, P\)"):
        check_measurements(np.zeros(shape))


def test_check_measurements_rejects_odd_rows_with_layout_explained():
    with pytest.raises(MeasurementError, match="W has 7 rows; it needs an even number") as error:
        check_measurements(np.zeros((7, 5)))
    assert "rows 2f, 2f+1 are x, y of frame f" in str(error.value)


def test_check_measurements_rejects_a_single_frame():
    with pytest.raises(MeasurementError, match=r"1 frame\(s\) \(2 rows\); at least 2"):
        check_measurements(np.zeros((2, 5)))


def test_check_measurements_honours_min_frames_and_min_points():
    W = np.zeros((6, 4))
    with pytest.raises(MeasurementError, match="at least 4 frames"):
        check_measurements(W, min_frames=4)
    with pytest.raises(MeasurementError, match=r"4 point\(s\).*at least 5"):
        check_measurements(W, min_points=5)
    assert check_measurements(W, min_frames=3, min_points=4).shape == (6, 4)


def test_check_measurements_reports_count_and_first_non_finite_entry():
    W = np.zeros((6, 5))
    W[3, 2] = np.nan  # y of frame 1, point 2
    W[4, 0] = np.nan
    W[5, 4] = np.inf
    with pytest.raises(MeasurementError) as error:
        check_measurements(W)
    message = str(error.value)
    assert "2 NaN and 1 infinite" in message
    assert "y of frame 1, point 2" in message


def test_check_measurements_catches_overflow_when_converting_to_float64():
    if np.finfo(np.longdouble).max <= np.finfo(np.float64).max:
        pytest.skip("long double is float64 on this platform")
    W = np.zeros((4, 3), dtype=np.longdouble)
    W[0, 0] = np.finfo(np.longdouble).max
    with pytest.raises(MeasurementError, match="infinite"):
        check_measurements(W)


# ---------------------------------------------------------------------------------------------
# tracks <-> W


def test_tracks_to_W_puts_x_and_y_of_frame_f_in_rows_2f_and_2f_plus_1():
    tracks = np.random.default_rng(2).normal(size=(3, 5, 2))
    W = tracks_to_W(tracks)
    assert W.shape == (6, 5)
    assert_array_equal(W[0::2], tracks[:, :, 0])
    assert_array_equal(W[1::2], tracks[:, :, 1])
    assert_array_equal(W_to_tracks(W), tracks)


@pytest.mark.parametrize("shape", [(3, 5), (3, 5, 3), (3, 5, 2, 1)])
def test_tracks_to_W_rejects_wrong_shapes(shape):
    with pytest.raises(MeasurementError, match=r"\(F, P, 2\)"):
        tracks_to_W(np.zeros(shape))


def test_W_to_tracks_rejects_odd_rows():
    with pytest.raises(MeasurementError, match="even number of rows"):
        W_to_tracks(np.zeros((5, 4)))


# ---------------------------------------------------------------------------------------------
# rotations, ground truth, faces, colours


def test_check_rotations_accepts_orthonormal_rows_and_returns_float64():
    R = random_rotations(5).astype(np.float32)
    checked = check_rotations(R, 5)
    assert checked.dtype == np.float64
    assert checked.shape == (5, 2, 3)


def test_check_rotations_names_the_first_failing_frame():
    R = random_rotations(6)
    R[4, 0] *= 1.01
    R[5, 1] *= 2.0
    with pytest.raises(MeasurementError, match=r"R of frame 4 .*2 frame\(s\) fail"):
        check_rotations(R, 6)


def test_check_rotations_tolerates_rounding_only():
    R = random_rotations(3)
    check_rotations(R * (1 + 1e-8), 3)
    with pytest.raises(MeasurementError, match="orthonormal"):
        check_rotations(R * (1 + 1e-5), 3)


def test_check_rotations_shape_messages():
    with pytest.raises(MeasurementError, match=r"needs \(4, 2, 3\)"):
        check_rotations(random_rotations(3), 4)
    with pytest.raises(MeasurementError, match=r"R.reshape\(-1, 2, 3\)"):
        check_rotations(random_rotations(4).reshape(8, 3), 4)


def test_check_rotations_rejects_nan():
    R = random_rotations(3)
    R[1, 0, 0] = np.nan
    with pytest.raises(MeasurementError, match="frame 1"):
        check_rotations(R, 3)


def test_check_ground_truth_shape_dtype_and_finiteness():
    gt = np.random.default_rng(3).normal(size=(3, 4, 3)).astype(np.float32)
    assert check_ground_truth(gt, 3, 4).dtype == np.float64
    with pytest.raises(MeasurementError, match=r"needs \(3, 5, 3\)"):
        check_ground_truth(gt, 3, 5)
    with pytest.raises(MeasurementError, match="transpose"):
        check_ground_truth(np.zeros((9, 4)), 3, 4)
    gt[2, 1, 0] = np.inf
    with pytest.raises(MeasurementError, match="frame 2"):
        check_ground_truth(gt, 3, 4)


def test_check_faces_converts_to_int64():
    faces = np.array([[0, 1, 2], [2, 3, 0]], dtype=np.uint16)
    checked = check_faces(faces, 4)
    assert checked.dtype == np.int64
    assert_array_equal(checked, faces)
    assert check_faces(np.zeros((0, 3), dtype=np.int32), 4).shape == (0, 3)


def test_check_faces_rejects_floats_with_a_conversion_hint():
    with pytest.raises(MeasurementError, match=r"astype\(np.int64\)"):
        check_faces(np.array([[0.0, 1.0, 2.0]]), 3)


def test_check_faces_rejects_out_of_range_and_spots_one_based_indices():
    with pytest.raises(MeasurementError, match=r"triangle 1: \[1, 2, 3\].*1-based"):
        check_faces(np.array([[1, 2, 1], [1, 2, 3]]), 3)
    with pytest.raises(MeasurementError, match=r"triangle 0: \[-1, 0, 1\]"):
        check_faces(np.array([[-1, 0, 1]]), 3)
    with pytest.raises(MeasurementError, match=r"\(M, 3\)"):
        check_faces(np.array([[0, 1, 2, 3]]), 4)


def test_check_colors_accepts_rgb_and_rgba():
    rgb = check_colors(np.array([[0, 128, 255], [1, 2, 3]], dtype=np.int64), 2)
    assert rgb.dtype == np.uint8
    assert_array_equal(rgb, [[0, 128, 255], [1, 2, 3]])
    assert check_colors(np.zeros((2, 4), dtype=np.uint8), 2).shape == (2, 4)


def test_check_colors_rejects_bad_values_types_and_shapes():
    with pytest.raises(MeasurementError, match="0..255"):
        check_colors(np.array([[0, 0, 256]]), 1)
    with pytest.raises(MeasurementError, match=r"colors \* 255"):
        check_colors(np.full((1, 3), 0.5), 1)
    with pytest.raises(MeasurementError, match=r"\(3, 3\) \(RGB\)"):
        check_colors(np.zeros((2, 3), dtype=np.uint8), 3)
    with pytest.raises(MeasurementError, match="booleans"):
        check_colors(np.zeros((1, 3), dtype=bool), 1)


def test_check_dtype_accepts_numbers_and_can_require_integers():
    check_dtype("W", np.float32)
    check_dtype("W", np.uint8)
    check_dtype("faces", np.int16, integer=True)
    with pytest.raises(MeasurementError, match="compound"):
        check_dtype("W", np.dtype([("a", "f8"), ("b", "f8")]))
    with pytest.raises(MeasurementError, match="needs integers"):
        check_dtype("faces", np.float64, integer=True)


# ---------------------------------------------------------------------------------------------
# check_observations


def occluded_W(n_frames: int = 5, n_points: int = 8, seed: int = 1) -> tuple[np.ndarray, ...]:
    """Random W with NaN at a few entries, and the matching visibility."""
    W = np.random.default_rng(seed).normal(size=(2 * n_frames, n_points))
    visibility = np.ones((n_frames, n_points), dtype=bool)
    visibility[0, 1] = visibility[2, 3] = visibility[2, 4] = visibility[4, 7] = False
    return with_missing(W, visibility), visibility


@pytest.mark.parametrize(
    "W",
    [
        np.arange(24, dtype=np.int32).reshape(4, 6),
        np.random.default_rng(2).normal(size=(6, 5)),
        np.asfortranarray(np.random.default_rng(3).normal(size=(6, 5))),
    ],
)
def test_check_observations_of_complete_data_is_check_measurements(W):
    filled, visibility = check_observations(W)
    expected = check_measurements(W)
    assert filled.dtype == expected.dtype and filled.flags.c_contiguous
    assert filled.tobytes() == expected.tobytes()
    assert visibility.shape == (W.shape[0] // 2, W.shape[1]) and visibility.all()
    if W.dtype == np.float64 and W.flags.c_contiguous:
        assert filled is W  # no copy, as check_measurements
    # An all-True mask changes nothing.
    again, _ = check_observations(W, np.ones_like(visibility))
    assert again.tobytes() == expected.tobytes()


def test_check_observations_fills_zeros_and_leaves_the_input_alone():
    W, expected = occluded_W()
    before = W.copy()
    filled, visibility = check_observations(W)
    assert_array_equal(visibility, expected)
    assert visibility.dtype == bool
    rows = np.repeat(expected, 2, axis=0)
    assert (filled[~rows] == 0.0).all() and np.isfinite(filled).all()
    assert_array_equal(filled[rows], W[rows])
    assert_array_equal(W, before)  # NaN still there
    # The same with the mask given: it agrees with the NaN.
    given, from_mask = check_observations(W, expected.astype(np.int8))
    assert_array_equal(given, filled) and from_mask.dtype == bool


def test_check_observations_refuses_a_disagreeing_visibility():
    W, visibility = occluded_W()
    wrong = visibility.copy()
    wrong[1, 1] = False  # W has a value there
    with pytest.raises(
        MeasurementError,
        match=r"disagree at 1 .*frame 1, point 1: visibility "
        r"says it is not observed but W holds a value",
    ):
        check_observations(W, wrong)
    wrong = visibility.copy()
    wrong[0, 1] = True  # W is NaN there
    with pytest.raises(MeasurementError, match="frame 0, point 1: visibility says it is observed"):
        check_observations(W, wrong)


def test_check_observations_refuses_nan_in_one_coordinate():
    W, _ = occluded_W()
    W[5, 0] = np.nan  # y of frame 2, point 0, its x stays
    with pytest.raises(MeasurementError, match="y of frame 2, point 0 .NaN while its x is not"):
        check_observations(W)


def test_check_observations_refuses_infinite_values():
    W, _ = occluded_W()
    W[6, 2] = -np.inf
    with pytest.raises(MeasurementError, match="1 infinite value.*x of frame 3, point 2.*never"):
        check_observations(W)


def test_check_observations_refuses_a_point_seen_in_one_frame():
    W, _ = occluded_W()
    W[2:, 5] = np.nan  # point 5: frame 0 only
    W[:8, 6] = np.nan  # point 6: frame 4 only
    with pytest.raises(MeasurementError) as error:
        check_observations(W)
    message = str(error.value)
    assert "2 point(s) are observed (not NaN) in fewer than 2 frames: point(s) 5, 6." in message
    assert "drop these points" in message


def test_check_observations_refuses_a_frame_with_too_few_points():
    W, _ = occluded_W()
    W[2:4, :6] = np.nan  # frame 1 keeps points 6 and 7 only
    with pytest.raises(MeasurementError) as error:
        check_observations(W)
    message = str(error.value)
    assert "1 frame(s) observe (not NaN) fewer than 3 points: frame(s) 1, with 2 " in message
    assert "drop these frames" in message


def test_check_observations_keeps_the_layout_checks():
    with pytest.raises(MeasurementError, match="even number"):
        check_observations(np.zeros((5, 4)))
    with pytest.raises(MeasurementError, match="visibility has shape"):
        check_observations(np.zeros((4, 4)), np.ones((2, 3), dtype=bool))
    with pytest.raises(MeasurementError, match="visibility holds floating-point"):
        check_observations(np.zeros((4, 4)), np.ones((2, 4)))
