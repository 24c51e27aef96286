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
    check_rotations,
    estimate_memory_bytes,
    tracks_to_W,
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
# memory estimate


def test_estimate_memory_bytes_follows_the_documented_formula():
    base = estimate_memory_bytes(0, 0)
    assert base == 128 * 2**20
    assert estimate_memory_bytes(99, 28_880) - base == 256 * 99 * 28_880
    # At least the eight (3F, P) float64 arrays the solver keeps.
    assert estimate_memory_bytes(10, 1000) >= 8 * 3 * 10 * 1000 * 8
    assert estimate_memory_bytes(20, 1000) > estimate_memory_bytes(10, 1000)


def test_estimate_memory_bytes_rejects_negative_sizes():
    with pytest.raises(ValueError, match="n_frames=-1"):
        estimate_memory_bytes(-1, 10)
