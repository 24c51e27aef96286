"""Tests of moju_core.ply: PLY export of points, faces and colours."""

from __future__ import annotations

import io

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from plyfile import PlyData

from moju_core.errors import MeasurementError
from moju_core.ply import (
    frame_file_name,
    ply_bytes,
    read_ply_points,
    write_ply,
    write_ply_frames,
)

N_POINTS = 7
FACES = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]])


@pytest.fixture
def points() -> np.ndarray:
    return np.random.default_rng(0).normal(scale=100.0, size=(N_POINTS, 3))


def parse(data: bytes) -> PlyData:
    return PlyData.read(io.BytesIO(data))


@pytest.mark.parametrize("binary", [True, False])
def test_points_round_trip(points, binary):
    data = ply_bytes(points, binary=binary)
    ply = parse(data)
    assert ply.text is not binary
    assert [element.name for element in ply.elements] == ["vertex"]
    assert ply["vertex"].data.dtype.names == ("x", "y", "z")
    assert ply["vertex"].data["x"].dtype == np.float32
    back = read_ply_points(data)
    assert back.shape == (N_POINTS, 3) and back.dtype == np.float64
    assert_allclose(back, points, rtol=1e-6)


@pytest.mark.parametrize("binary", [True, False])
def test_faces_and_colours_round_trip(points, binary):
    colors = np.random.default_rng(1).integers(0, 256, size=(N_POINTS, 3))
    ply = parse(ply_bytes(points, faces=FACES, colors=colors, binary=binary))
    vertices = ply["vertex"].data
    assert vertices.dtype.names == ("x", "y", "z", "red", "green", "blue")
    assert_array_equal(np.column_stack([vertices[c] for c in ("red", "green", "blue")]), colors)
    assert vertices["red"].dtype == np.uint8
    faces = np.vstack(ply["face"].data["vertex_indices"])
    assert_array_equal(faces, FACES)
    assert faces.dtype == np.int32


def test_rgba_colours_add_an_alpha_channel(points):
    colors = np.full((N_POINTS, 4), 200, dtype=np.uint8)
    colors[:, 3] = 17
    vertices = parse(ply_bytes(points, colors=colors))["vertex"].data
    assert vertices.dtype.names[-1] == "alpha"
    assert_array_equal(vertices["alpha"], 17)


def test_faces_without_colours(points):
    ply = parse(ply_bytes(points, faces=FACES))
    assert [element.name for element in ply.elements] == ["vertex", "face"]
    assert ply["vertex"].data.dtype.names == ("x", "y", "z")


def test_write_ply_and_read_back_from_a_path(tmp_path, points):
    path = write_ply(tmp_path / "shape.ply", points, faces=FACES)
    assert path.read_bytes() == ply_bytes(points, faces=FACES)
    assert_allclose(read_ply_points(path), points, rtol=1e-6)
    with open(path, "rb") as handle:
        assert_allclose(read_ply_points(handle), points, rtol=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == ["shape.ply"]


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"points": np.zeros((5, 2))}, r"shape \(P, 3\)"),
        ({"points": np.full((3, 3), np.nan)}, "finite"),
        ({"points": np.zeros((3, 3), dtype=complex)}, "complex"),
        ({"points": np.zeros((3, 3)), "faces": [[0, 1, 3]]}, "outside 0..2"),
        ({"points": np.zeros((3, 3)), "colors": np.full((3, 3), 0.5)}, "0..255"),
        ({"points": np.zeros((3, 3)), "colors": np.zeros((2, 3), dtype=np.uint8)}, r"\(3, 3\)"),
    ],
)
def test_bad_input_is_refused(kwargs, fragment):
    with pytest.raises(MeasurementError, match=fragment):
        ply_bytes(**kwargs)


def test_frame_names_are_zero_padded_to_at_least_four_digits():
    assert frame_file_name(0, 1) == "frame_0000.ply"
    assert frame_file_name(42, 99) == "frame_0042.ply"
    assert frame_file_name(9999, 10_000) == "frame_9999.ply"
    assert frame_file_name(3, 10_001) == "frame_00003.ply"
    assert frame_file_name(10_000, 10_001) == "frame_10000.ply"


def test_write_ply_frames_writes_one_file_per_frame(tmp_path):
    shapes = np.random.default_rng(2).normal(size=(3, N_POINTS, 3))
    colors = np.random.default_rng(3).integers(0, 256, size=(N_POINTS, 3))
    directory = tmp_path / "frames" / "nested"
    paths = write_ply_frames(directory, shapes, faces=FACES, colors=colors)
    assert [p.name for p in paths] == ["frame_0000.ply", "frame_0001.ply", "frame_0002.ply"]
    assert sorted(p.name for p in directory.iterdir()) == [p.name for p in paths]
    for frame, path in enumerate(paths):
        # Later frames reuse the header and face block of the first; they must be identical
        # to what plyfile writes for that frame on its own.
        assert path.read_bytes() == ply_bytes(shapes[frame], faces=FACES, colors=colors)
        assert_allclose(read_ply_points(path), shapes[frame], rtol=1e-6)


def test_write_ply_frames_without_faces(tmp_path):
    shapes = np.random.default_rng(4).normal(size=(2, N_POINTS, 3))
    paths = write_ply_frames(tmp_path, shapes)
    assert [element.name for element in PlyData.read(paths[1]).elements] == ["vertex"]
    assert_allclose(read_ply_points(paths[1]), shapes[1], rtol=1e-6)


def test_write_ply_frames_checks_shapes(tmp_path):
    with pytest.raises(MeasurementError, match=r"\(F, P, 3\)"):
        write_ply_frames(tmp_path, np.zeros((4, 3)))
    shapes = np.zeros((2, 3, 3))
    shapes[1, 0, 0] = np.inf
    with pytest.raises(MeasurementError, match=r"shapes\[1\]"):
        write_ply_frames(tmp_path / "bad", shapes)


def test_read_ply_points_rejects_garbage():
    with pytest.raises(MeasurementError, match="could not read the PLY"):
        read_ply_points(b"not a ply file at all")
