"""HDF5 links: nothing that leaves the file is followed, at any depth; admission from headers."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from numpy.testing import assert_array_equal

from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.io import read_measurements

W = np.random.default_rng(3).normal(size=(6, 10))


@pytest.fixture
def other_file(tmp_path: Path) -> Path:
    """Another file of the machine, holding a perfectly good W (that must not be read)."""
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as h5:
        h5.create_dataset("group/W", data=W)
        h5.create_dataset("W", data=W)
    return path


def _write(path: Path, build) -> Path:
    with h5py.File(path, "w") as h5:
        build(h5)
    return path


def _refused(path: Path) -> str:
    with pytest.raises(MeasurementError) as error:
        read_measurements(path)
    return str(error.value)


def test_soft_link_into_an_external_link_is_refused(tmp_path: Path, other_file: Path) -> None:
    def build(h5: h5py.File) -> None:
        h5["outside"] = h5py.ExternalLink(str(other_file), "/group")
        h5["W"] = h5py.SoftLink("/outside/W")

    assert "W in in.h5 is a link to another file" in _refused(_write(tmp_path / "in.h5", build))


def test_chain_of_soft_links_to_an_external_link_deep_in_groups_is_refused(
    tmp_path: Path, other_file: Path
) -> None:
    def build(h5: h5py.File) -> None:
        h5.create_group("a/b")
        h5["a/b/c"] = h5py.ExternalLink(str(other_file), "/group")
        h5["a/next"] = h5py.SoftLink("b/c")  # relative to /a
        h5["hop"] = h5py.SoftLink("/a/next")
        h5["W"] = h5py.SoftLink("/hop/W")

    assert "link to another file" in _refused(_write(tmp_path / "in.h5", build))


def test_soft_links_that_loop_are_refused(tmp_path: Path) -> None:
    def build(h5: h5py.File) -> None:
        h5["x"] = h5py.SoftLink("/y")
        h5["y"] = h5py.SoftLink("/x")
        h5["W"] = h5py.SoftLink("/x/W")

    assert "loop" in _refused(_write(tmp_path / "in.h5", build))


def test_dangling_soft_link_is_refused(tmp_path: Path) -> None:
    path = _write(tmp_path / "in.h5", lambda h5: h5.__setitem__("W", h5py.SoftLink("/none")))
    assert "link to nothing" in _refused(path)


def test_soft_link_inside_the_file_is_followed(tmp_path: Path) -> None:
    def build(h5: h5py.File) -> None:
        h5.create_dataset("data/tracks2d", data=W)
        h5["alias"] = h5py.SoftLink("/data")
        h5["W"] = h5py.SoftLink("alias/tracks2d")

    assert_array_equal(read_measurements(_write(tmp_path / "in.h5", build)).W, W)


def _calls(record: list):
    def admit(n_frames: int, n_points: int) -> None:
        record.append((n_frames, n_points))
        raise MeasurementTooLarge("refused by admit")

    return admit


def test_admit_sees_the_declared_size_of_every_format(tmp_path: Path) -> None:
    record: list = []
    npz = io.BytesIO()
    np.savez(npz, W=W)
    h5 = _write(tmp_path / "w.h5", lambda f: f.create_dataset("W", data=W))
    csv = "frame,point,x,y\n" + "".join(
        f"{f},{p},{W[2 * f, p]},{W[2 * f + 1, p]}\n" for f in range(3) for p in range(10)
    )
    for source in (io.BytesIO(npz.getvalue()), h5, io.BytesIO(csv.encode())):
        with pytest.raises(MeasurementTooLarge, match="refused by admit"):
            read_measurements(source, admit=_calls(record))
    assert record == [(3, 10)] * 3


def test_npz_member_is_not_decompressed_when_admit_refuses() -> None:
    buffer = io.BytesIO()
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": (6, 10)}
    )
    with zipfile.ZipFile(buffer, "w") as archive:
        # Data that would fail to parse if it were read: the refusal must come first.
        archive.writestr("W.npy", header.getvalue() + b"\xff" * 480)
    with pytest.raises(MeasurementTooLarge, match="refused by admit"):
        read_measurements(io.BytesIO(buffer.getvalue()), admit=_calls([]))


def test_csv_line_without_end_is_refused_without_reading_it_whole() -> None:
    text = b"frame,point,x,y\n" + b"0," * 3000
    with pytest.raises(MeasurementError, match="line 2 of the uploaded file is longer than 4096"):
        read_measurements(io.BytesIO(text), format="csv")
    with pytest.raises(MeasurementError, match="line 1 of the uploaded file is longer than 4096"):
        read_measurements(io.BytesIO(b"frame" * 5000), format="csv")
