"""The camera matrix (moju_core.cameras.intrinsics): construction, checks, the pixel-to-ray
map and the text file reader."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from moju_core.cameras.intrinsics import (
    DEFAULT_FOCAL_FACTOR,
    Intrinsics,
    check_frame_size,
    check_intrinsics_matrix,
    read_intrinsics,
)
from moju_core.errors import MeasurementError

K = np.array([[528.0144, 0.0, 320.0], [0.0, 528.0144, 240.0], [0.0, 0.0, 1.0]])


def test_from_focal_puts_the_principal_point_at_the_centre_of_the_pixel_grid():
    camera = Intrinsics.from_focal(500.0, (640, 480))
    # Pixel centres at integers: the centre of 640 x 480 pixels is between 319 and 320.
    assert camera.principal_point == (319.5, 239.5)
    assert camera.fx == camera.fy == 500.0 and camera.skew == 0.0
    assert camera.origin == "focal"


def test_the_default_is_colmaps_focal_length_and_says_so():
    camera = Intrinsics.default_for((640, 480))
    assert DEFAULT_FOCAL_FACTOR == 1.2
    assert camera.fx == camera.fy == pytest.approx(768.0)
    assert Intrinsics.default_for((480, 640)).fx == pytest.approx(768.0)  # the larger side
    assert camera.origin == "default"
    assert camera.to_metadata() == {"K": camera.K.tolist(), "origin": "default"}


def test_k_is_a_read_only_copy():
    given = K.copy()
    camera = Intrinsics(given)
    given[0, 0] = 1.0
    assert camera.fx == K[0, 0]
    with pytest.raises(ValueError):
        camera.K[0, 0] = 2.0


def test_normalise_applies_the_inverse_of_k_and_keeps_nan():
    skewed = np.array([[500.0, 3.0, 300.0], [0.0, 450.0, 200.0], [0.0, 0.0, 1.0]])
    camera = Intrinsics(skewed)
    rng = np.random.default_rng(0)
    W = rng.uniform(0, 640, size=(6, 5))
    W[2:4, 1] = np.nan
    rays = camera.normalise(W)
    for frame in range(3):
        pixels = np.vstack([W[2 * frame : 2 * frame + 2], np.ones(5)])
        expected = np.linalg.solve(skewed, np.nan_to_num(pixels))[:2]
        observed = np.isfinite(W[2 * frame])
        assert_allclose(rays[2 * frame : 2 * frame + 2][:, observed], expected[:, observed])
    assert_array_equal(np.isnan(rays), np.isnan(W))
    assert_allclose(camera.to_pixels(rays), W)
    # The image centre maps to the optical axis.
    centre = Intrinsics.from_focal(100.0, (11, 21))
    assert_allclose(centre.normalise([[5.0], [10.0]]), [[0.0], [0.0]])


@pytest.mark.parametrize(
    ("matrix", "fragment"),
    [
        (np.eye(4), "shape (4, 4)"),
        (np.array([["a"] * 3] * 3), "dtype <U1"),
        (np.array([[1.0, 0, np.nan], [0, 1, 0], [0, 0, 1]]), "NaN or infinite"),
        (np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 2]]), "divide K by K[2, 2]"),
        (np.array([[1.0, 0, 0], [0.5, 1, 0], [0, 0, 1]]), "K[1, 0] is 0.5"),
        (np.array([[-1.0, 0, 0], [0, 1, 0], [0, 0, 1]]), "both must be positive"),
        (np.array([[1.0, 0, 0], [0, 0, 0], [0, 0, 1]]), "fy = 0"),
    ],
)
def test_bad_matrices_are_refused_with_the_fix(matrix, fragment):
    with pytest.raises(MeasurementError, match="upper-triangular") as error:
        check_intrinsics_matrix(matrix)
    assert fragment in str(error.value)


@pytest.mark.parametrize(
    ("size", "fragment"),
    [
        ((640.0, 480.0), "must be two integers"),
        ((640, 480, 3), "must be two integers"),
        ((0, 480), "between 1 and"),
        ((10**6, 480), "between 1 and"),
    ],
)
def test_bad_frame_sizes_are_refused(size, fragment):
    with pytest.raises(MeasurementError, match=fragment):
        check_frame_size(np.array(size))


def test_focal_must_be_positive():
    with pytest.raises(MeasurementError, match="positive number of pixels"):
        Intrinsics.from_focal(0.0, (640, 480))
    with pytest.raises(MeasurementError, match="positive number of pixels"):
        Intrinsics.from_focal(float("nan"), (640, 480))


@pytest.mark.parametrize(
    "text",
    [
        "   528.0144,0,320\n   0,528.0144,240\n   0,0,1",  # as shipped with a data set
        "# K of the kinect\n528.0144 0 320\n\n0 528.0144 240\n0 0 1\n",
        "528.0144, 0, 320\r\n0, 528.0144, 240\r\n0, 0, 1\r\n",
    ],
)
def test_read_intrinsics_takes_commas_or_spaces(tmp_path, text):
    path = tmp_path / "K.txt"
    path.write_text(text)
    camera = read_intrinsics(path)
    assert_array_equal(camera.K, K)
    assert camera.origin == "given"


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (b"1 0 0\n0 1 0\n", "2 row(s)"),
        (b"1 0 0 4\n0 1 0\n0 0 1\n", "three lines of three numbers"),
        (b"1 0 zero\n0 1 0\n0 0 1\n", "'1 0 zero' is not a row of numbers"),
        (b"\xff\xfe\x00binary", "not a text file"),
        (b"0 " * 40_000, "larger than 64 KiB"),
        (b"1 0 0\n0 1 0\n0 0 3\n", "not [0, 0, 1]"),
    ],
)
def test_read_intrinsics_refuses_what_is_not_k(tmp_path, content, fragment):
    path = tmp_path / "K.txt"
    path.write_bytes(content)
    with pytest.raises(MeasurementError, match="K.txt") as error:
        read_intrinsics(path)
    assert fragment in str(error.value)


def test_read_intrinsics_of_a_missing_file(tmp_path):
    with pytest.raises(MeasurementError, match="could not read missing.txt"):
        read_intrinsics(tmp_path / "missing.txt")


def test_parse_intrinsics_reads_an_upload_as_the_file_reader_does():
    from moju_core.cameras.intrinsics import parse_intrinsics

    camera = parse_intrinsics(b"528.0144 0 320\n0 528.0144 240\n0 0 1\n", "the form field")
    assert_array_equal(camera.K, K)
    with pytest.raises(MeasurementError, match="^the form field holds 1 row"):
        parse_intrinsics(b"1 2 3", "the form field")
