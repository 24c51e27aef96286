"""Tests of moju_core.io: the input/output file contract, including hostile input."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import tempfile
import zipfile
from pathlib import Path

import h5py
import numpy as np
import numpy.lib.format as npy_format
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.testing import assert_allclose, assert_array_equal

import moju_core
from moju_core import io as moju_io
from moju_core.errors import MeasurementError
from moju_core.io import (
    Measurements,
    atomic_output,
    read_measurements,
    read_result,
    write_measurements,
    write_result,
)
from moju_core.params import SolverParams
from moju_core.result import Diagnostics, Result, RotationRigidity, TrajectoryBasisFit
from moju_core.validation import W_to_tracks

N_FRAMES, N_POINTS = 4, 6


@pytest.fixture
def full() -> Measurements:
    """Measurements with every optional dataset."""
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(N_FRAMES, 3, 3)))
    return Measurements(
        W=rng.normal(size=(2 * N_FRAMES, N_POINTS)),
        rotations=q[:, :2, :],
        ground_truth=rng.normal(size=(N_FRAMES, N_POINTS, 3)),
        faces=np.array([[0, 1, 2], [3, 4, 5]]),
        colors=rng.integers(0, 256, size=(N_POINTS, 3)),
    )


def assert_same_measurements(actual: Measurements, expected: Measurements) -> None:
    assert_array_equal(actual.W, expected.W)  # NaN at the same places counts as equal
    for name in ("visibility", "rotations", "ground_truth", "faces", "colors"):
        got, want = getattr(actual, name), getattr(expected, name)
        if want is None:
            assert got is None, name
        else:
            assert_array_equal(got, want, err_msg=name)
            assert got.dtype == want.dtype, name


def csv_text(W: np.ndarray, order: np.ndarray | None = None, columns=("frame", "point", "x", "y")):
    """Long-format CSV of W written independently of moju_core.io, rows in ``order``."""
    tracks = W_to_tracks(W)
    n_frames, n_points, _ = tracks.shape
    rows = [
        {
            "frame": str(f),
            "point": str(p),
            "x": repr(float(tracks[f, p, 0])),
            "y": repr(float(tracks[f, p, 1])),
        }
        for f in range(n_frames)
        for p in range(n_points)
    ]
    if order is not None:
        rows = [rows[i] for i in order]
    lines = [",".join(columns)]
    lines += [",".join(row.get(column, "extra") for column in columns) for row in rows]
    return "\n".join(lines) + "\n"


def npy_header_only(shape: tuple[int, ...], dtype: str = "<f8") -> bytes:
    """A .npy member that declares ``shape`` but carries no data."""
    buffer = io.BytesIO()
    npy_format.write_array_header_1_0(
        buffer, {"descr": dtype, "fortran_order": False, "shape": shape}
    )
    return buffer.getvalue()


# ---------------------------------------------------------------------------------------------
# Round trips


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".hdf5"])
def test_write_then_read_keeps_every_dataset(tmp_path, full, suffix):
    path = write_measurements(tmp_path / f"input{suffix}", full)
    assert_same_measurements(read_measurements(path), full)


def test_csv_round_trip_through_write_measurements(tmp_path, full):
    only_tracks = Measurements(W=full.W)
    path = write_measurements(tmp_path / "input.csv", only_tracks)
    assert path.read_text().startswith("frame,point,x,y\n")
    assert_same_measurements(read_measurements(path), only_tracks)


def missing_visibility() -> np.ndarray:
    """A (4, 6) mask with 5 unobserved entries; every point in >= 2 frames, every frame >= 3."""
    visibility = np.ones((N_FRAMES, N_POINTS), dtype=bool)
    visibility[0, 1] = visibility[1, 2] = visibility[1, 3] = visibility[2, 5] = False
    visibility[3, 0] = False
    return visibility


@pytest.fixture
def occluded(full) -> Measurements:
    """``full`` with the points of missing_visibility() not observed (NaN in W)."""
    visibility = missing_visibility()
    W = full.W.copy()
    W[np.repeat(~visibility, 2, axis=0)] = np.nan
    return Measurements(
        W=W,
        rotations=full.rotations,
        ground_truth=full.ground_truth,
        faces=full.faces,
        colors=full.colors,
    )


def test_measurements_derive_the_visibility_from_nan(occluded):
    assert_array_equal(occluded.visibility, missing_visibility())
    assert np.isnan(occluded.W[np.repeat(~missing_visibility(), 2, axis=0)]).all()
    assert occluded.observed_fraction == pytest.approx(19 / 24)


def test_complete_measurements_have_no_visibility(full):
    assert full.visibility is None and full.observed_fraction == 1.0
    # An all-True mask says nothing the data do not: it is dropped.
    again = Measurements(W=full.W, visibility=np.ones((N_FRAMES, N_POINTS), dtype=bool))
    assert again.visibility is None
    assert_array_equal(again.W, full.W)


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".csv"])
def test_nan_and_visibility_round_trip(tmp_path, occluded, suffix):
    expected = occluded if suffix != ".csv" else Measurements(W=occluded.W)
    path = write_measurements(tmp_path / f"occluded{suffix}", expected)
    read = read_measurements(path)
    assert_same_measurements(read, expected)
    assert_array_equal(read.visibility, missing_visibility())
    if suffix == ".csv":  # one row per observed pair, none for the others
        assert len(path.read_text().splitlines()) == 1 + int(missing_visibility().sum())
    else:
        with np.load(path) if suffix == ".npz" else h5py.File(path, "r") as stored:
            assert stored["visibility"].dtype == bool


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_visibility_with_tracks_is_read(tmp_path, occluded, suffix):
    tracks = W_to_tracks(occluded.W)
    path = tmp_path / f"tracks{suffix}"
    arrays = {"tracks": tracks, "visibility": missing_visibility().astype(np.uint8)}
    if suffix == ".npz":
        np.savez(path, **arrays)
    else:
        with h5py.File(path, "w") as h5:
            for name, value in arrays.items():
                h5[name] = value
    read = read_measurements(path)
    assert_array_equal(read.visibility, missing_visibility())
    assert_array_equal(read.W, occluded.W)


def test_disagreeing_visibility_is_refused(tmp_path, full):
    visibility = missing_visibility()
    np.savez(tmp_path / "disagree.npz", W=full.W, visibility=visibility)  # W has no NaN
    with pytest.raises(MeasurementError, match="W and visibility disagree at 5") as error:
        read_measurements(tmp_path / "disagree.npz")
    assert "frame 0, point 1: visibility says it is not observed" in str(error.value)
    W = full.W.copy()
    W[np.repeat(~visibility, 2, axis=0)] = np.nan
    W[2:4, 0] = np.nan  # frame 1, point 0: observed according to visibility
    np.savez(tmp_path / "disagree2.npz", W=W, visibility=visibility)
    with pytest.raises(MeasurementError, match="frame 1, point 0: visibility says it is "):
        read_measurements(tmp_path / "disagree2.npz")


@pytest.mark.parametrize(
    ("visibility", "fragment"),
    [
        (np.ones((N_FRAMES, N_POINTS - 1), dtype=bool), r"visibility has shape \(4, 5\)"),
        (np.full((N_FRAMES, N_POINTS), 2), "values from 2 to 2"),
        (np.ones((N_FRAMES, N_POINTS)), "visibility holds floating-point numbers"),
    ],
)
def test_bad_visibility_dataset_is_refused(tmp_path, full, visibility, fragment):
    np.savez(tmp_path / "bad.npz", W=full.W, visibility=visibility)
    with pytest.raises(MeasurementError, match=fragment):
        read_measurements(tmp_path / "bad.npz")


def test_point_observed_in_one_frame_is_refused(tmp_path, full):
    W = full.W.copy()
    W[2:, 4] = np.nan  # point 4 only in frame 0
    np.savez(tmp_path / "one.npz", W=W)
    with pytest.raises(MeasurementError, match=r"1 point\(s\) are observed .*point\(s\) 4\."):
        read_measurements(tmp_path / "one.npz")


def test_csv_writer_refuses_to_drop_optional_datasets(tmp_path, full):
    with pytest.raises(ValueError, match="colors, faces, gt"):
        write_measurements(tmp_path / "input.csv", full)
    assert list(tmp_path.iterdir()) == []


def test_write_measurements_needs_a_known_extension(tmp_path, full):
    with pytest.raises(ValueError, match=r"\.npz, \.h5, \.hdf5 or \.csv"):
        write_measurements(tmp_path / "input.mat", full)


def test_npz_with_tracks_instead_of_W(tmp_path, full):
    path = tmp_path / "tracks.npz"
    np.savez(path, tracks=W_to_tracks(full.W), R=full.rotations)
    read = read_measurements(path)
    assert_array_equal(read.W, full.W)
    assert_array_equal(read.rotations, full.rotations)
    assert read.ground_truth is None and read.faces is None and read.colors is None


def test_h5_with_tracks_instead_of_W(tmp_path, full):
    path = tmp_path / "tracks.h5"
    with h5py.File(path, "w") as h5:
        h5["tracks"] = W_to_tracks(full.W).astype(np.float32)
        h5["gt"] = full.ground_truth
    read = read_measurements(path)
    assert_allclose(read.W, full.W, rtol=1e-6)
    assert read.W.dtype == np.float64
    assert_array_equal(read.ground_truth, full.ground_truth)


def test_unknown_datasets_are_ignored(tmp_path, full):
    np.savez(tmp_path / "extra.npz", W=full.W, notes=np.array(["hello"]), arr_0=np.zeros(3))
    assert_array_equal(read_measurements(tmp_path / "extra.npz").W, full.W)
    with h5py.File(tmp_path / "extra.h5", "w") as h5:
        h5["W"] = full.W
        h5.create_group("provenance")["camera"] = np.array([b"unknown"])
    assert_array_equal(read_measurements(tmp_path / "extra.h5").W, full.W)


def test_integer_W_is_accepted_and_converted(tmp_path):
    W = np.arange(12, dtype=np.int16).reshape(4, 3)
    np.savez(tmp_path / "int.npz", W=W)
    read = read_measurements(tmp_path / "int.npz")
    assert read.W.dtype == np.float64
    assert_array_equal(read.W, W)


def test_fortran_ordered_npz_member_is_read_correctly(tmp_path, full):
    np.savez(tmp_path / "f.npz", W=np.asfortranarray(full.W))
    assert_array_equal(read_measurements(tmp_path / "f.npz").W, full.W)


# ---------------------------------------------------------------------------------------------
# Format detection


def file_bytes(tmp_path: Path, suffix: str, measurements: Measurements) -> bytes:
    return write_measurements(tmp_path / f"source{suffix}", measurements).read_bytes()


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".csv"])
def test_format_is_detected_from_the_content_of_a_nameless_file_object(tmp_path, full, suffix):
    measurements = full if suffix != ".csv" else Measurements(W=full.W)
    upload = io.BytesIO(file_bytes(tmp_path, suffix, measurements))
    upload.seek(5)  # the reader starts from the beginning whatever the position
    assert_same_measurements(read_measurements(upload), measurements)


def test_magic_bytes_win_over_a_misleading_extension(tmp_path, full):
    path = tmp_path / "really_npz.csv"
    path.write_bytes(file_bytes(tmp_path, ".npz", full))
    assert_same_measurements(read_measurements(path), full)


def test_named_file_object_uses_its_extension_when_content_is_unknown(tmp_path, full):
    path = tmp_path / "broken.npz"
    path.write_bytes(b"this is not a zip")
    with open(path, "rb") as handle, pytest.raises(MeasurementError, match="as npz"):
        read_measurements(handle)


def test_explicit_format_overrides_detection(tmp_path, full):
    data = csv_text(full.W).encode()
    assert_array_equal(read_measurements(io.BytesIO(data), format="csv").W, full.W)
    with pytest.raises(MeasurementError, match="could not read the uploaded file as npz"):
        read_measurements(io.BytesIO(data), format="npz")
    with pytest.raises(MeasurementError, match="unknown input format 'mat'"):
        read_measurements(io.BytesIO(data), format="mat")


def test_non_seekable_file_object_is_buffered(tmp_path, full):
    class Pipe(io.RawIOBase):
        def __init__(self, data: bytes) -> None:
            self._stream = io.BytesIO(data)

        def readable(self) -> bool:
            return True

        def readinto(self, buffer) -> int:
            chunk = self._stream.read(len(buffer))
            buffer[: len(chunk)] = chunk
            return len(chunk)

    data = file_bytes(tmp_path, ".npz", full)
    assert_same_measurements(read_measurements(io.BufferedReader(Pipe(data))), full)


def test_bare_npy_file_gets_a_hint(tmp_path, full):
    np.save(tmp_path / "W.npy", full.W)
    with pytest.raises(MeasurementError, match=r"np.savez\(path, W=W\)"):
        read_measurements(tmp_path / "W.npy")


def test_missing_file_is_a_measurement_error(tmp_path):
    with pytest.raises(MeasurementError, match="could not open nowhere.npz"):
        read_measurements(tmp_path / "nowhere.npz")


# ---------------------------------------------------------------------------------------------
# Hostile or broken npz


def test_npz_with_pickled_object_array_is_refused_clearly(tmp_path):
    np.savez(tmp_path / "pickle.npz", W=np.array([{}], dtype=object))
    with pytest.raises(MeasurementError, match="Python objects.*never pickles"):
        read_measurements(tmp_path / "pickle.npz")


def test_pickled_optional_dataset_is_refused(tmp_path, full):
    np.savez(tmp_path / "pickle.npz", W=full.W, R=np.array([{}], dtype=object))
    with pytest.raises(MeasurementError, match="R holds Python objects"):
        read_measurements(tmp_path / "pickle.npz")


def test_pickled_unknown_member_is_never_loaded(tmp_path, full):
    np.savez(tmp_path / "pickle.npz", full.W, W=full.W, evil=np.array([{}], dtype=object))
    assert_array_equal(read_measurements(tmp_path / "pickle.npz").W, full.W)


def test_missing_W_names_the_expected_datasets(tmp_path):
    np.savez(tmp_path / "none.npz", measurements=np.zeros((4, 5)))
    with pytest.raises(MeasurementError, match=r"no dataset named W or tracks.*\(F x P x 2\)"):
        read_measurements(tmp_path / "none.npz")


def test_W_and_tracks_together_are_ambiguous(tmp_path, full):
    np.savez(tmp_path / "both.npz", W=full.W, tracks=W_to_tracks(full.W))
    with pytest.raises(MeasurementError, match="both W and tracks"):
        read_measurements(tmp_path / "both.npz")


@pytest.mark.parametrize(
    ("W", "fragment"),
    [
        (np.zeros((7, 5)), "W has 7 rows; it needs an even number"),
        (np.zeros((2, 5)), r"1 frame\(s\)"),
        (np.zeros((4, 2)), r"2 point\(s\)"),
        (np.zeros(10), r"shape \(10,\) \(1-D\)"),
        (np.ones((4, 5), dtype=complex), "complex"),
        (np.full((4, 5), "a"), "strings"),
    ],
)
def test_bad_W_in_npz(tmp_path, W, fragment):
    np.savez(tmp_path / "bad.npz", W=W)
    with pytest.raises(MeasurementError, match=fragment):
        read_measurements(tmp_path / "bad.npz")


def test_nan_in_npz_is_located(tmp_path, full):
    W = full.W.copy()
    W[5, 3] = np.nan
    np.savez(tmp_path / "nan.npz", W=W)
    with pytest.raises(MeasurementError, match="one coordinate NaN.*y of frame 2, point 3"):
        read_measurements(tmp_path / "nan.npz")


def test_inconsistent_optional_dataset_is_refused(tmp_path, full):
    np.savez(tmp_path / "r.npz", W=full.W, R=full.rotations[:-1])
    with pytest.raises(MeasurementError, match=r"R has shape \(3, 2, 3\)"):
        read_measurements(tmp_path / "r.npz")


def test_truncated_npz_is_a_measurement_error(tmp_path, full):
    data = file_bytes(tmp_path, ".npz", full)
    for cut in (len(data) // 2, len(data) - 10, 40):
        path = tmp_path / f"cut{cut}.npz"
        path.write_bytes(data[:cut])
        with pytest.raises(MeasurementError, match=f"could not read cut{cut}.npz as npz"):
            read_measurements(path)


def test_corrupt_member_data_is_a_measurement_error(tmp_path, full):
    path = tmp_path / "crc.npz"
    np.savez(path, W=full.W)  # stored uncompressed: flipping a data byte breaks the CRC
    data = bytearray(path.read_bytes())
    position = data.index(full.W.tobytes()[:16])
    data[position] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(MeasurementError, match="could not read crc.npz as npz"):
        read_measurements(path)


def test_header_declaring_a_huge_W_is_refused_before_reading(tmp_path, monkeypatch):
    path = tmp_path / "huge.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("W.npy", npy_header_only((2_000_000, 1_000_000)))

    def no_data_reads(*args, **kwargs):
        raise AssertionError("array data must not be read")

    monkeypatch.setattr(npy_format, "read_array", no_data_reads)
    with pytest.raises(MeasurementError) as error:
        read_measurements(path, max_frames=1000, max_points=50_000)
    message = str(error.value)
    assert "1000000 frames x 1000000 points" in message
    assert "1000 frames and 50000 points" in message
    # Without limits the header still does not make us allocate 16 TB: the member is too short.
    with pytest.raises(MeasurementError, match="truncated"):
        read_measurements(path)


def test_real_oversized_npz_is_refused_without_reading_its_data(tmp_path, monkeypatch):
    path = tmp_path / "big.npz"
    np.savez(path, W=np.zeros((2 * 50, 20)))
    calls = []
    original = npy_format.read_array
    monkeypatch.setattr(
        npy_format, "read_array", lambda *a, **k: calls.append(1) or original(*a, **k)
    )
    with pytest.raises(MeasurementError, match="50 frames x 20 points.*limit is 10 frames"):
        read_measurements(path, max_frames=10)
    with pytest.raises(MeasurementError, match="limit is 19 points"):
        read_measurements(path, max_points=19)
    assert calls == []
    assert read_measurements(path, max_frames=50, max_points=20).n_frames == 50
    assert calls == [1]


def test_optional_dataset_declaring_too_much_is_refused_before_reading(tmp_path, full):
    path = tmp_path / "gt.npz"
    with zipfile.ZipFile(path, "w") as archive:
        with archive.open("W.npy", "w") as member:
            npy_format.write_array(member, full.W)
        archive.writestr("gt.npy", npy_header_only((10**9, 10**6, 3)))
    with pytest.raises(MeasurementError, match="gt in gt.npz declares shape"):
        read_measurements(path)


def test_faces_are_bounded_when_limits_are_set(tmp_path, full):
    path = tmp_path / "faces.npz"
    np.savez(path, W=full.W, faces=np.zeros((4 * 10 + 1, 3), dtype=np.int32))
    with pytest.raises(MeasurementError, match="faces in faces.npz declares shape"):
        read_measurements(path, max_points=10)
    assert read_measurements(path, max_points=11).faces.shape == (41, 3)


def test_limits_must_be_positive_integers(tmp_path, full):
    path = write_measurements(tmp_path / "ok.npz", full)
    with pytest.raises(ValueError, match="max_points"):
        read_measurements(path, max_points=0)


# ---------------------------------------------------------------------------------------------
# Hostile or broken HDF5


def write_h5(path: Path, **datasets) -> Path:
    with h5py.File(path, "w") as h5:
        for name, value in datasets.items():
            h5[name] = value
    return path


def test_h5_string_dataset_is_refused(tmp_path):
    path = write_h5(tmp_path / "s.h5", W=np.array(["1", "2"], dtype=h5py.string_dtype()))
    with pytest.raises(MeasurementError, match="W holds"):
        read_measurements(path)
    path = write_h5(tmp_path / "b.h5", W=np.array([[b"1", b"2"]] * 4))
    with pytest.raises(MeasurementError, match="byte strings"):
        read_measurements(path)


def test_h5_compound_dataset_is_refused(tmp_path):
    records = np.zeros(4, dtype=[("x", "f8"), ("y", "f8")])
    with pytest.raises(MeasurementError, match="compound"):
        read_measurements(write_h5(tmp_path / "c.h5", W=records))


def test_h5_ragged_dataset_is_refused(tmp_path):
    path = tmp_path / "ragged.h5"
    with h5py.File(path, "w") as h5:
        ragged = h5.create_dataset("W", (4,), dtype=h5py.vlen_dtype(np.float64))
        for row in range(4):
            ragged[row] = np.arange(row + 1, dtype=np.float64)
    with pytest.raises(MeasurementError, match="variable-length"):
        read_measurements(path)


def test_h5_group_named_W_is_refused(tmp_path):
    path = tmp_path / "group.h5"
    with h5py.File(path, "w") as h5:
        h5.create_group("W")["data"] = np.zeros((4, 5))
    with pytest.raises(MeasurementError, match="W in group.h5 is an HDF5 group"):
        read_measurements(path)


def test_h5_dataset_nested_in_a_group_is_not_found(tmp_path):
    path = tmp_path / "nested.h5"
    with h5py.File(path, "w") as h5:
        h5.create_group("data")["W"] = np.zeros((4, 5))
    with pytest.raises(MeasurementError, match="no dataset named W or tracks"):
        read_measurements(path)


def test_h5_links_to_other_files_are_refused(tmp_path, full):
    write_h5(tmp_path / "secret.h5", W=full.W)
    path = tmp_path / "link.h5"
    with h5py.File(path, "w") as h5:
        h5["W"] = h5py.ExternalLink("secret.h5", "/W")
    with pytest.raises(MeasurementError, match="link to another file"):
        read_measurements(path)


def test_h5_external_raw_storage_is_refused(tmp_path):
    raw = tmp_path / "raw.bin"
    np.zeros((4, 5)).tofile(raw)
    path = tmp_path / "external.h5"
    with h5py.File(path, "w") as h5:
        h5.create_dataset("W", shape=(4, 5), dtype="<f8", external=[(str(raw), 0, 160)])
    with pytest.raises(MeasurementError, match="refers to data in other files"):
        read_measurements(path)


def test_h5_oversized_dataset_is_refused_from_its_shape(tmp_path):
    path = tmp_path / "huge.h5"
    with h5py.File(path, "w") as h5:
        # Chunked and never written: the file is tiny but declares 16 TB.
        h5.create_dataset("W", shape=(2_000_000, 1_000_000), dtype="f8", chunks=(64, 64))
    assert path.stat().st_size < 100_000
    with pytest.raises(MeasurementError, match="1000000 frames x 1000000 points.*1000 frames"):
        read_measurements(path, max_frames=1000)


def test_truncated_h5_is_a_measurement_error(tmp_path, full):
    data = file_bytes(tmp_path, ".h5", full)
    path = tmp_path / "cut.h5"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(MeasurementError, match="could not read cut.h5 as HDF5"):
        read_measurements(path)


# ---------------------------------------------------------------------------------------------
# CSV


def test_csv_column_order_is_free_and_extra_columns_are_ignored(full):
    text = csv_text(full.W, columns=("y", "note", "point", "x", "frame"))
    order = np.random.default_rng(5).permutation(N_FRAMES * N_POINTS)
    shuffled = csv_text(full.W, order=order)
    assert_array_equal(read_measurements(io.BytesIO(text.encode())).W, full.W)
    assert_array_equal(read_measurements(io.BytesIO(shuffled.encode())).W, full.W)


def test_csv_with_bom_crlf_spaces_and_quotes():
    text = '\ufeff Frame , Point ,X,Y\r\n0,0,"1.5",2\r\n0,1,3,4\r\n0,2,5,6\r\n'
    text += "1,0,7,8\r\n1,1,9,10\r\n1,2,11,12\r\n\r\n"
    W = read_measurements(io.BytesIO(text.encode("utf-8")), format="csv").W
    assert_array_equal(W, [[1.5, 3, 5], [2, 4, 6], [7, 9, 11], [8, 10, 12]])


def csv_error(text: str) -> str:
    with pytest.raises(MeasurementError) as error:
        read_measurements(io.BytesIO(text.encode()), format="csv")
    return str(error.value)


def test_csv_missing_column():
    assert "lacks column(s) y" in csv_error("frame,point,x\n0,0,1\n")


def test_csv_header_the_csv_module_refuses_is_a_measurement_error():
    # A lone carriage return inside the header (found by the fuzz test): csv.Error before.
    assert "not a valid CSV header" in csv_error("frame,po\rint,x,y\n0,0,1,1\n")


def test_csv_repeated_column():
    assert "x twice" in csv_error("frame,point,x,x,y\n0,0,1,1,1\n")


def test_csv_non_numeric_cell_names_line_and_column(full):
    lines = csv_text(full.W).splitlines()
    lines[7] = "1,0,oops,2.0"
    message = csv_error("\n".join(lines))
    assert "line 8" in message and "column x" in message and "'oops'" in message


def test_csv_short_row_names_the_line(full):
    lines = csv_text(full.W).splitlines()
    lines[3] = "0,2"
    assert "line 4 of the uploaded file has 2 column(s)" in csv_error("\n".join(lines))


def test_csv_missing_row_is_an_unobserved_point(full):
    lines = csv_text(full.W).splitlines()
    del lines[1 + N_POINTS + 2]  # frame 1, point 2
    read = read_measurements(io.BytesIO("\n".join(lines).encode()), format="csv")
    expected = np.ones((N_FRAMES, N_POINTS), dtype=bool)
    expected[1, 2] = False
    assert_array_equal(read.visibility, expected)
    assert np.isnan(read.W[2:4, 2]).all()
    assert_array_equal(read.W[np.repeat(expected, 2, axis=0)], full.W[np.repeat(expected, 2, 0)])
    assert read.observed_fraction == pytest.approx(1 - 1 / (N_FRAMES * N_POINTS))


def test_csv_row_of_nan_is_an_unobserved_point(full):
    lines = csv_text(full.W).splitlines()
    lines[1 + N_POINTS + 2] = "1,2,nan,nan"
    read = read_measurements(io.BytesIO("\n".join(lines).encode()), format="csv")
    assert not read.visibility[1, 2] and read.visibility.sum() == N_FRAMES * N_POINTS - 1


def test_csv_point_in_one_frame_only_is_refused(full):
    lines = csv_text(full.W).splitlines()
    # Point 4 keeps only its row of frame 0.
    kept = [line for line in lines if not (line.split(",")[1] == "4" and line[0] != "0")]
    message = csv_error("\n".join(kept))
    assert "1 point(s) are observed (not NaN) in fewer than 2 frames: point(s) 4" in message
    assert "drop these points" in message


def test_csv_duplicated_pair_is_listed(full):
    lines = csv_text(full.W).splitlines()
    lines.append(lines[1 + 2 * N_POINTS + 4])  # frame 2, point 4 again
    message = csv_error("\n".join(lines))
    assert "1 are repeated, e.g. (frame 2, point 4)" in message


def test_csv_indices_must_be_whole_numbers_in_range(full):
    lines = csv_text(full.W).splitlines()
    lines[2] = "0,1.5,1,1"
    assert "line 3" in csv_error("\n".join(lines)) and "point is 1.5" in csv_error("\n".join(lines))
    lines[2] = "-1,1,1,1"
    assert "frame is -1" in csv_error("\n".join(lines))
    lines[2] = "0,1000000000000000000,1,1"
    assert "point is 1e+18" in csv_error("\n".join(lines))


def test_csv_stray_large_index_does_not_allocate_frames_times_points():
    n_rows = 2000
    frames, points = np.divmod(np.arange(n_rows), 2)
    points[-1] = n_rows - 1  # F x P becomes 1000 x 2000 = 2e6 pairs from 2000 rows
    text = "frame,point,x,y\n" + "".join(
        f"{f},{p},0,0\n" for f, p in zip(frames, points, strict=True)
    )
    # Refused from the rows alone (each frame sees 2 points), before a 1000 x 2000 W exists.
    message = csv_error(text)
    assert "1998 point(s) are observed (not NaN) in fewer than 2 frames" in message


def test_csv_empty_and_header_only():
    assert "lacks column(s) frame, point, x, y" in csv_error("")
    assert "no data rows" in csv_error("frame,point,x,y\n")


def test_csv_with_nan_is_located(full):
    lines = csv_text(full.W).splitlines()
    lines[1 + N_POINTS + 1] = "1,1,nan,0"
    assert "x of frame 1, point 1" in csv_error("\n".join(lines))


def test_csv_single_frame_is_refused(full):
    text = csv_text(full.W[:2])
    assert "1 frame(s)" in csv_error(text)


def test_csv_respects_limits(full):
    data = csv_text(full.W).encode()
    with pytest.raises(MeasurementError, match="4 frames x 6 points.*limit is 3 frames"):
        read_measurements(io.BytesIO(data), max_frames=3)


def test_binary_garbage_is_reported_as_not_text():
    with pytest.raises(MeasurementError, match="neither npz, HDF5 nor UTF-8 text"):
        read_measurements(io.BytesIO(bytes(range(256))))


def test_large_csv_is_read(tmp_path):
    n_frames, n_points = 50, 2000
    W = np.random.default_rng(6).normal(size=(2 * n_frames, n_points))
    path = write_measurements(tmp_path / "large.csv", Measurements(W=W))
    assert_array_equal(read_measurements(path).W, W)


@settings(
    max_examples=50,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(
    data=st.data(),
    n_frames=st.integers(2, 6),
    n_points=st.integers(3, 8),
)
def test_random_W_survives_npz_and_csv(data, n_frames, n_points):
    W = data.draw(
        arrays(
            np.float64,
            (2 * n_frames, n_points),
            elements=st.floats(allow_nan=False, allow_infinity=False, width=64),
        )
    )
    order = np.array(data.draw(st.permutations(range(n_frames * n_points))))
    with tempfile.TemporaryDirectory() as directory:
        path = write_measurements(Path(directory) / "w.npz", Measurements(W=W))
        assert_array_equal(read_measurements(path).W, W)
    from_csv = read_measurements(io.BytesIO(csv_text(W, order=order).encode()))
    assert_array_equal(from_csv.W, W)


# ---------------------------------------------------------------------------------------------
# Results


@pytest.fixture
def result() -> Result:
    rng = np.random.default_rng(7)
    q, _ = np.linalg.qr(rng.normal(size=(N_FRAMES, 3, 3)))
    n_iter = 5
    return Result(
        shapes=rng.normal(size=(N_FRAMES, N_POINTS, 3)),
        rotations=q[:, :2, :],
        labels=np.array([0, 0, 1, 1, 2, 2]),
        history={
            "gap": np.geomspace(1.0, 1e-6, n_iter),
            "rho": 0.01 * 1.1 ** np.arange(n_iter),
            "relabelled": np.array([3, 1, 0, 0, 0]),
        },
        timings={"rotations": 0.5, "iterate": np.float64(2.25), "total": 3.0},
        params=SolverParams(n_groups=3, seed=4),
        n_iter=n_iter,
        stop_reason="max_iter",
        scale=12.5,
    )


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".hdf5"])
def test_result_round_trip(tmp_path, result, suffix):
    metadata = {"job_id": "abc", "input": "face.npz", "n_points": np.int64(6)}
    path = write_result(tmp_path / f"result{suffix}", result, metadata=metadata)
    loaded = read_result(path)
    assert_array_equal(loaded.shapes, result.shapes)
    assert_array_equal(loaded.rotations, result.rotations)
    assert_array_equal(loaded.labels, result.labels)
    assert loaded.labels.dtype == np.int64
    assert set(loaded.history) == set(result.history)
    for key, values in result.history.items():
        assert_array_equal(loaded.history[key], values)
    assert loaded.params == result.params
    assert loaded.timings == {"rotations": 0.5, "iterate": 2.25, "total": 3.0}
    assert isinstance(loaded, Result) and loaded.diagnostics is None
    assert loaded.n_iter == 5 and isinstance(loaded.n_iter, int)
    assert loaded.stop_reason == "max_iter"
    assert loaded.scale == 12.5
    assert loaded.version == moju_core.__version__
    assert loaded.metadata == {"job_id": "abc", "input": "face.npz", "n_points": 6}
    # Written again without metadata, a result read back keeps its own.
    again = read_result(write_result(tmp_path / f"again{suffix}", loaded))
    assert again.metadata == loaded.metadata
    (tmp_path / f"again{suffix}").unlink()
    assert (loaded.n_frames, loaded.n_points) == (N_FRAMES, N_POINTS)
    assert [p.name for p in tmp_path.iterdir()] == [f"result{suffix}"]


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_result_visibility_round_trip(tmp_path, result, suffix):
    visibility = missing_visibility()
    with_mask = dataclasses.replace(result, visibility=visibility)
    loaded = read_result(write_result(tmp_path / f"occluded{suffix}", with_mask))
    assert loaded.visibility.dtype == bool
    assert_array_equal(loaded.visibility, visibility)
    # A result without a mask solved complete data: the file says every entry was observed.
    complete = read_result(write_result(tmp_path / f"complete{suffix}", result))
    assert complete.visibility.all() and complete.visibility.shape == (N_FRAMES, N_POINTS)


def test_result_visibility_must_match_the_shapes(tmp_path, result):
    wrong = dataclasses.replace(result, visibility=np.ones((N_FRAMES, N_POINTS - 1), dtype=bool))
    with pytest.raises(ValueError, match=r"result.visibility \(4, 5\) does not match"):
        write_result(tmp_path / "wrong.npz", wrong)
    assert not any(tmp_path.iterdir())


def test_result_file_without_visibility_reads_as_none(tmp_path, result):
    path = write_result(tmp_path / "old.h5", result)
    with h5py.File(path, "a") as h5:
        del h5["visibility"]  # as written before the dataset existed
    assert read_result(path).visibility is None


DIAGNOSTICS = Diagnostics(
    n_groups_used=2,
    rotation_source="windowed",
    rotation_window=10,
    rotations_refined=True,
    rotation_rigidity=RotationRigidity(intersection=0.25, windowed=0.01),
    noise_variance=0.5,
    observed_fraction=0.75,
    smoothness_trials=((0.0, 0.1), (3.0, 0.2)),
    trajectory_basis=TrajectoryBasisFit(rank=9, condition=float("inf")),
)


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_result_diagnostics_round_trip(tmp_path, result, suffix):
    with_diagnostics = dataclasses.replace(result, diagnostics=DIAGNOSTICS)
    loaded = read_result(write_result(tmp_path / f"r{suffix}", with_diagnostics))
    assert loaded.diagnostics == DIAGNOSTICS


def _rewrite_json(path: Path, key: str, value: object) -> None:
    """Replace one JSON document of an HDF5 result, as an older or newer writer would."""
    with h5py.File(path, "a") as h5:
        if value is None:
            del h5.attrs[key]
        else:
            h5.attrs[key] = json.dumps(value)


def test_result_file_with_params_that_no_longer_exist_reads(tmp_path, result):
    path = write_result(tmp_path / "old.h5", result)
    stored = {**result.params.model_dump(mode="json"), "retired_option": 3}
    del stored["smoothness"]  # written before the parameter existed
    _rewrite_json(path, "params", stored)
    assert read_result(path).params == result.params.model_copy(update={"smoothness": None})


def test_result_file_with_a_refused_parameter_value_is_unreadable(tmp_path, result):
    path = write_result(tmp_path / "bad.h5", result)
    _rewrite_json(path, "params", {**result.params.model_dump(mode="json"), "max_iter": -1})
    with pytest.raises(ValueError, match="(?s)not a readable MoJu result file.*max_iter"):
        read_result(path)


@pytest.mark.parametrize(
    "stored",
    [None, {"rotation_source": "windowed"}, {**DIAGNOSTICS.to_dict(), "rotation_source": "x"}],
    ids=["absent", "field-missing", "unknown-source"],
)
def test_result_file_without_usable_diagnostics_reads_them_as_none(tmp_path, result, stored):
    path = write_result(tmp_path / "old.h5", dataclasses.replace(result, diagnostics=DIAGNOSTICS))
    _rewrite_json(path, "diagnostics", stored)
    loaded = read_result(path)
    assert loaded.diagnostics is None
    assert_array_equal(loaded.shapes, result.shapes)


def test_result_file_diagnostics_ignore_unknown_keys(tmp_path, result):
    path = write_result(tmp_path / "new.h5", dataclasses.replace(result, diagnostics=DIAGNOSTICS))
    _rewrite_json(path, "diagnostics", {**DIAGNOSTICS.to_dict(), "added_later": 1})
    assert read_result(path).diagnostics == DIAGNOSTICS


def test_npz_result_loads_without_pickles(tmp_path, result):
    path = write_result(tmp_path / "result.npz", result)
    with np.load(path, allow_pickle=False) as npz:
        assert {"shapes", "rotations", "labels", "history_gap", "params"} <= set(npz.files)
        assert json.loads(str(npz["params"]))["n_groups"] == 3
        assert npz["n_iter"].shape == ()
    assert read_result(path).metadata == {}


def test_h5_result_layout(tmp_path, result):
    path = write_result(tmp_path / "result.h5", result)
    with h5py.File(path, "r") as h5:
        assert h5["shapes"].shape == (N_FRAMES, N_POINTS, 3)
        assert list(h5["history"]) == ["gap", "rho", "relabelled"]
        assert h5.attrs["stop_reason"] == "max_iter"
        assert json.loads(h5.attrs["timings"])["total"] == 3.0


def test_write_result_needs_a_known_extension(tmp_path, result):
    with pytest.raises(ValueError, match=r"\.npz, \.h5 or \.hdf5"):
        write_result(tmp_path / "result.mat", result)
    assert list(tmp_path.iterdir()) == []


def test_write_result_checks_consistency_before_touching_disk(tmp_path, result):
    result.labels = np.zeros(N_POINTS + 1, dtype=np.int64)
    with pytest.raises(ValueError, match="do not match"):
        write_result(tmp_path / "result.h5", result)
    assert list(tmp_path.iterdir()) == []


def test_unserialisable_metadata_fails_before_touching_disk(tmp_path, result):
    with pytest.raises(TypeError, match="object is not JSON serialisable"):
        write_result(tmp_path / "result.npz", result, metadata={"x": object()})
    assert list(tmp_path.iterdir()) == []


def test_read_result_rejects_other_files(tmp_path, full):
    path = write_measurements(tmp_path / "input.npz", full)
    with pytest.raises(ValueError, match="not a readable MoJu result file"):
        read_result(path)
    path = write_measurements(tmp_path / "input.h5", full)
    with pytest.raises(ValueError, match="not a readable MoJu result file"):
        read_result(path)


# ---------------------------------------------------------------------------------------------
# Atomic writes


def test_failing_npz_writer_leaves_nothing_behind(tmp_path, result, monkeypatch):
    def half_write(file, **arrays):
        file.write(b"PK\x03\x04 half a zip")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", half_write)
    with pytest.raises(OSError, match="disk full"):
        write_result(tmp_path / "result.npz", result)
    assert list(tmp_path.iterdir()) == []


def test_failing_h5_writer_leaves_nothing_behind_and_keeps_the_old_file(
    tmp_path, result, monkeypatch
):
    path = write_result(tmp_path / "result.h5", result)
    old = path.read_bytes()
    original = h5py.Group.create_dataset

    def fail_on_labels(self, name, *args, **kwargs):
        if name == "labels":
            raise RuntimeError("killed midway")
        return original(self, name, *args, **kwargs)

    monkeypatch.setattr(h5py.Group, "create_dataset", fail_on_labels)
    result.scale = 99.0
    with pytest.raises(RuntimeError, match="killed midway"):
        write_result(path, result)
    assert [p.name for p in tmp_path.iterdir()] == ["result.h5"]
    assert path.read_bytes() == old


def test_atomic_output_only_shows_the_final_file_after_success(tmp_path):
    target = tmp_path / "out.bin"
    with atomic_output(target) as temporary:
        assert temporary.parent == tmp_path
        assert temporary.exists() and not target.exists()
        temporary.write_bytes(b"done")
    assert target.read_bytes() == b"done"
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]


def test_atomic_output_gives_normal_permissions(tmp_path):
    previous = os.umask(0o022)
    try:
        with atomic_output(tmp_path / "out.bin") as temporary:
            temporary.write_bytes(b"x")
    finally:
        os.umask(previous)
    assert (tmp_path / "out.bin").stat().st_mode & 0o777 == 0o644


def test_module_exports_are_importable():
    for name in moju_io.__all__:
        assert hasattr(moju_io, name), name
