"""Property-based tests of the file readers against hostile bytes (the service's uploads).

Whatever the bytes, :func:`moju_core.io.read_measurements` either returns measurements that
satisfy the contract (float64 W of shape 2F x P, F >= 2, P >= 3, within the limits, NaN
only at the unobserved entries of its visibility)
or raises :class:`~moju_core.errors.MeasurementError`: never another exception, which the
API would turn into a 500.
"""

from __future__ import annotations

import io
import warnings

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays, scalar_dtypes
from numpy.testing import assert_array_equal

from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.io import Measurements, read_measurements

FORMATS = ("npz", "h5", "csv")
FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
#: For the properties that write HDF5 files (slower to build): fewer examples.
FEWER = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _read(data: bytes, file_format: str | None, **limits: int) -> Measurements | None:
    """Read, returning None on a MeasurementError; any other exception fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # overflow in checks of huge values
        try:
            measurements = read_measurements(io.BytesIO(data), format=file_format, **limits)
        except MeasurementError:
            return None
    _check_contract(measurements, **limits)
    return measurements


def _check_contract(m: Measurements, max_frames: int | None = None, max_points=None) -> None:
    assert m.W.dtype == np.float64 and m.W.ndim == 2 and m.W.shape[0] % 2 == 0
    assert m.n_frames >= 2 and m.n_points >= 3
    assert not np.isinf(m.W).any()
    # NaN (x and y together) exactly at the unobserved entries; a mask only when one is.
    observed = np.isfinite(m.W).reshape(m.n_frames, 2, m.n_points).all(axis=1)
    assert_array_equal(np.isnan(m.W), np.repeat(~observed, 2, axis=0))
    if m.visibility is None:
        assert observed.all()
    else:
        assert_array_equal(m.visibility, observed)
        assert not observed.all()
        assert (observed.sum(axis=0) >= 2).all() and (observed.sum(axis=1) >= 3).all()
    if max_frames is not None:
        assert m.n_frames <= max_frames
    if max_points is not None:
        assert m.n_points <= max_points
    if m.rotations is not None:
        assert m.rotations.shape == (m.n_frames, 2, 3)
    if m.faces is not None:
        assert m.faces.ndim == 2 and m.faces.shape[1] == 3
        assert m.faces.size == 0 or (m.faces.min() >= 0 and m.faces.max() < m.n_points)


def _npz_bytes(**arrays_: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays_)
    return buffer.getvalue()


def _h5_bytes(**arrays_: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as h5:
        for name, value in arrays_.items():
            h5.create_dataset(name, data=value)
    return buffer.getvalue()


def _csv_bytes(W: np.ndarray) -> bytes:
    """Long-format CSV of W; entries with x and y both NaN get no row (unobserved)."""
    n_frames, n_points = W.shape[0] // 2, W.shape[1]
    rows = ["frame,point,x,y"]
    for frame in range(n_frames):
        for point in range(n_points):
            x, y = float(W[2 * frame, point]), float(W[2 * frame + 1, point])
            if not (np.isnan(x) and np.isnan(y)):
                rows.append(f"{frame},{point},{x!r},{y!r}")
    return ("\n".join(rows) + "\n").encode()


def _valid_file(file_format: str) -> bytes:
    rng = np.random.default_rng(3)
    W = rng.normal(size=(8, 12))
    rotations = np.tile(np.eye(3)[:2], (4, 1, 1))
    faces = np.array([[0, 1, 2], [3, 4, 5], [9, 10, 11]])
    if file_format == "npz":
        return _npz_bytes(W=W, R=rotations, faces=faces)
    if file_format == "h5":
        return _h5_bytes(W=W, R=rotations, faces=faces)
    return _csv_bytes(W)


VALID = {file_format: _valid_file(file_format) for file_format in FORMATS}


@FAST
@given(data=st.binary(max_size=2048), file_format=st.sampled_from([*FORMATS, None]))
def test_arbitrary_bytes_are_read_or_refused_cleanly(data: bytes, file_format) -> None:
    _read(data, file_format)


@FAST
@given(
    file_format=st.sampled_from(FORMATS),
    edits=st.lists(
        st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=8
    ),  # fmt: skip
    cut=st.one_of(st.none(), st.floats(0, 1)),
)
def test_corrupted_files_are_read_or_refused_cleanly(file_format, edits, cut) -> None:
    data = bytearray(VALID[file_format])
    for where, value in edits:
        data[int(where * len(data))] = value
    if cut is not None:
        data = data[: int(cut * len(data))]
    _read(bytes(data), file_format)


@FAST
@given(
    W=arrays(
        dtype=scalar_dtypes(),
        shape=array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=7),
    ),
    file_format=st.sampled_from(["npz", "h5"]),
    name=st.sampled_from(["W", "tracks"]),
)
def test_any_numpy_array_as_the_tracks(W: np.ndarray, file_format: str, name: str) -> None:
    """Any dtype (dates, strings, complex, booleans, ...) and any shape."""
    try:
        data = (_npz_bytes if file_format == "npz" else _h5_bytes)(**{name: W})
    except (TypeError, ValueError):  # h5py cannot store some dtypes at all
        return
    read = _read(data, file_format)
    if read is not None:
        assert W.dtype.kind in "fiu"
        expected = W if name == "W" else W.transpose(0, 2, 1).reshape(-1, W.shape[1])
        assert_array_equal(read.W, expected.astype(np.float64))


CELLS = st.one_of(
    st.integers(-3, 12).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", " ", "abc", "1e999", "0x10", '"3"', "nan", "-inf", "1,2", "\x00"]),
)


@FAST
@given(
    header=st.permutations(["frame", "point", "x", "y", "extra"]).map(
        lambda names: ",".join(names[: 4 + (names[0] == "extra")])
    ),
    rows=st.lists(st.lists(CELLS, min_size=0, max_size=6), max_size=30),
    newline=st.sampled_from(["\n", "\r\n"]),
)
def test_arbitrary_csv_is_read_or_refused_cleanly(header: str, rows, newline: str) -> None:
    text = newline.join([header, *(",".join(row) for row in rows)])
    _read(text.encode(), "csv")


@FEWER
@given(
    n_frames=st.integers(2, 9),
    n_points=st.integers(3, 9),
    max_frames=st.integers(2, 9),
    max_points=st.integers(3, 9),
    file_format=st.sampled_from(FORMATS),
)
def test_limits_refuse_exactly_what_exceeds_them(
    n_frames, n_points, max_frames, max_points, file_format
) -> None:
    W = np.arange(2 * n_frames * n_points, dtype=np.float64).reshape(2 * n_frames, n_points)
    W = np.sin(W)  # finite, varied
    data = {"npz": _npz_bytes, "h5": _h5_bytes}.get(file_format, None)
    raw = data(W=W) if data else _csv_bytes(W)
    too_big = n_frames > max_frames or n_points > max_points
    try:
        read = read_measurements(
            io.BytesIO(raw), format=file_format, max_frames=max_frames, max_points=max_points
        )
    except MeasurementTooLarge:
        assert too_big
        return
    assert not too_big
    assert_array_equal(read.W, W)


@FEWER
@given(
    W=arrays(
        np.float64,
        st.tuples(st.integers(2, 6).map(lambda f: 2 * f), st.integers(3, 8)),
        elements=st.floats(allow_nan=False, allow_infinity=False, width=64),
    ),
)
def test_every_format_keeps_every_bit_of_finite_tracks(W: np.ndarray) -> None:
    for raw, file_format in ((_npz_bytes(W=W), "npz"), (_h5_bytes(W=W), "h5"),
                             (_csv_bytes(W), "csv")):  # fmt: skip
        read = read_measurements(io.BytesIO(raw), format=file_format)
        assert_array_equal(read.W, W)
        assert read.W.tobytes() == np.ascontiguousarray(W).tobytes()  # even -0.0


@pytest.mark.parametrize("file_format", FORMATS)
def test_the_valid_base_files_are_valid(file_format: str) -> None:
    """The corruption test starts from files that are read correctly."""
    read = _read(VALID[file_format], file_format)
    assert read is not None and read.W.shape == (8, 12)


@FEWER
@given(
    W=arrays(
        np.float64,
        st.tuples(st.integers(2, 6).map(lambda f: 2 * f), st.integers(3, 8)),
        elements=st.floats(allow_nan=False, allow_infinity=False, width=64),
    ),
    data=st.data(),
)
def test_missing_points_survive_every_format_or_are_refused(W: np.ndarray, data) -> None:
    """Random entries unobserved (NaN): each format reads the same W and visibility, or all
    three refuse (too few observations), and the observed values keep every bit."""
    n_frames, n_points = W.shape[0] // 2, W.shape[1]
    hidden = data.draw(arrays(np.bool_, (n_frames, n_points)))
    W = W.copy()
    W[np.repeat(hidden, 2, axis=0)] = np.nan
    outcomes = []
    for raw, file_format in ((_npz_bytes(W=W), "npz"), (_h5_bytes(W=W), "h5"),
                             (_csv_bytes(W), "csv")):  # fmt: skip
        outcomes.append(_read(raw, file_format))
    if outcomes[0] is None:
        assert all(outcome is None for outcome in outcomes)
        observed = ~hidden
        assert (observed.sum(axis=0) < 2).any() or (observed.sum(axis=1) < 3).any()
        return
    for read in outcomes:
        assert read.W.tobytes() == W.tobytes()  # NaN at the same places, the rest bit for bit
        if hidden.any():
            assert_array_equal(read.visibility, ~hidden)
        else:
            assert read.visibility is None
