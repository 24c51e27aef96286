"""The camera in the file contract (K and frame_size of moju_core.io) and the tracks seen in
one frame only that a reader may leave out (``short_tracks="drop"``)."""

from __future__ import annotations

import io
import warnings

import h5py
import numpy as np
import pytest
from numpy.testing import assert_array_equal

from moju_core.cameras.intrinsics import Intrinsics
from moju_core.errors import MeasurementError
from moju_core.io import Measurements, read_measurements, write_measurements

K = np.array([[500.0, 0.0, 330.0], [0.0, 510.0, 250.0], [0.0, 0.0, 1.0]])


def _tracks(n_frames: int = 4, n_points: int = 8, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0, 600, size=(2 * n_frames, n_points))


def _npz(**arrays) -> io.BytesIO:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    return buffer


# --- K and frame_size ----------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_k_and_frame_size_round_trip(tmp_path, suffix):
    written = Measurements(W=_tracks(), intrinsics=K, frame_size=(640, 480))
    assert written.intrinsics.origin == "given"
    path = write_measurements(tmp_path / f"tracks{suffix}", written)
    read = read_measurements(path)
    assert_array_equal(read.intrinsics.K, K)
    assert read.intrinsics.origin == "given"
    assert read.frame_size == (640, 480)


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_a_frame_size_without_k_reads_as_the_default_camera(tmp_path, suffix):
    path = write_measurements(
        tmp_path / f"tracks{suffix}", Measurements(W=_tracks(), frame_size=(640, 480))
    )
    # The default is not stored: it is the frame size's, and reads back as "default".
    if suffix == ".npz":
        with np.load(path) as data:
            assert "K" not in data.files and list(data["frame_size"]) == [640, 480]
    else:
        with h5py.File(path) as h5:
            assert "K" not in h5
    read = read_measurements(path)
    assert read.intrinsics.origin == "default"
    assert_array_equal(read.intrinsics.K, Intrinsics.default_for((640, 480)).K)


def test_tracks_without_a_frame_size_have_no_camera():
    measurements = read_measurements(_npz(W=_tracks()))
    assert measurements.intrinsics is None and measurements.frame_size is None


def test_k_without_a_frame_size_is_kept():
    measurements = read_measurements(_npz(W=_tracks(), K=K))
    assert_array_equal(measurements.intrinsics.K, K)
    assert measurements.frame_size is None


@pytest.mark.parametrize(
    ("arrays", "fragment"),
    [
        ({"K": np.eye(4)}, "K in the uploaded file has shape (4, 4); it needs shape (3, 3)"),
        ({"K": np.zeros((2000, 2000))}, "shape (3, 3)"),
        ({"K": np.array(["fx"] * 9).reshape(3, 3)}, "K holds strings"),
        ({"K": np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 0]])}, "not [0, 0, 1]"),
        ({"K": np.diag([0.0, 1.0, 1.0])}, "both must be positive"),
        ({"frame_size": np.array([640.0, 480.0])}, "frame_size holds floating-point"),
        ({"frame_size": np.array([640, 480, 3])}, "frame_size in the uploaded file has shape"),
        ({"frame_size": np.array([0, 480])}, "between 1 and"),
    ],
)
def test_bad_cameras_are_refused_with_the_fix(arrays, fragment):
    with pytest.raises(MeasurementError) as error:
        read_measurements(_npz(W=_tracks(), **arrays))
    assert fragment in str(error.value)


def test_camera_datasets_are_checked_before_their_data_is_read(monkeypatch):
    """An oversized K is refused from its header: its data is never read."""
    import numpy.lib.format as npy_format

    upload = _npz(W=_tracks(), K=np.zeros((3000, 3000)))
    read_array = npy_format.read_array
    shapes = []

    def watched(stream, *args, **kwargs):
        array = read_array(stream, *args, **kwargs)
        shapes.append(array.shape)
        return array

    monkeypatch.setattr(npy_format, "read_array", watched)
    with pytest.raises(MeasurementError, match="shape"):
        read_measurements(upload)
    assert shapes == []


def test_csv_cannot_hold_the_camera(tmp_path):
    with pytest.raises(ValueError, match="frame_size"):
        write_measurements(tmp_path / "t.csv", Measurements(W=_tracks(), frame_size=(64, 48)))


# --- tracks seen in one frame only ---------------------------------------------------------


def _with_short_tracks() -> tuple[np.ndarray, np.ndarray]:
    """W (8 x 8, 4 frames) whose points 1 and 5 are seen in frame 0 only."""
    W = _tracks()
    visibility = np.ones((4, 8), dtype=bool)
    visibility[1:, [1, 5]] = False
    W[np.repeat(~visibility, 2, axis=0)] = np.nan
    return W, visibility


def test_short_tracks_are_refused_unless_asked_to_drop():
    W, _ = _with_short_tracks()
    with pytest.raises(MeasurementError, match=r"point\(s\) 1, 5"):
        read_measurements(_npz(W=W))


def test_short_tracks_are_dropped_with_everything_that_belongs_to_them():
    W, visibility = _with_short_tracks()
    truth = np.random.default_rng(1).normal(size=(4, 8, 3))
    colors = np.arange(24, dtype=np.uint8).reshape(8, 3)
    faces = np.array([[0, 1, 2], [2, 3, 4], [4, 6, 7], [5, 6, 7]])
    upload = _npz(W=W, visibility=visibility, gt=truth, colors=colors, faces=faces,
                  frame_size=np.array([640, 480]))  # fmt: skip
    with pytest.warns(UserWarning, match=r"^2 of 8 tracks are seen in fewer than 2 frames"):
        measurements = read_measurements(upload, short_tracks="drop")
    keep = [0, 2, 3, 4, 6, 7]
    assert_array_equal(measurements.W, W[:, keep])
    assert measurements.visibility is None  # what is left is complete
    assert_array_equal(measurements.ground_truth, truth[:, keep])
    assert_array_equal(measurements.colors, colors[keep])
    # Triangles with a dropped corner go; the others are renumbered.
    assert_array_equal(measurements.faces, [[1, 2, 3], [3, 4, 5]])
    assert measurements.frame_size == (640, 480)


def test_dropping_nothing_warns_nothing():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        measurements = read_measurements(_npz(W=_tracks()), short_tracks="drop")
    assert measurements.n_points == 8


def test_csv_drops_short_tracks_too():
    W, visibility = _with_short_tracks()
    frames, points = np.nonzero(visibility)
    rows = ["frame,point,x,y"] + [
        f"{f},{p},{float(W[2 * f, p])!r},{float(W[2 * f + 1, p])!r}"
        for f, p in zip(frames, points, strict=True)
    ]
    upload = io.BytesIO("\n".join(rows).encode())
    with pytest.warns(UserWarning, match="2 of 8 tracks"):
        measurements = read_measurements(upload, format="csv", short_tracks="drop")
    assert measurements.n_points == 6


def test_dropping_can_still_leave_a_frame_too_thin():
    W, visibility = _with_short_tracks()
    W[4:, 2:] = np.nan  # frames 2 and 3 keep point 0 only (1 and 5 are gone)
    visibility[2:, 2:] = False
    with pytest.warns(UserWarning), pytest.raises(MeasurementError, match="fewer than 3"):
        read_measurements(_npz(W=W), short_tracks="drop")


def test_short_tracks_option_is_checked():
    with pytest.raises(ValueError, match="short_tracks"):
        read_measurements(_npz(W=_tracks()), short_tracks="keep")
