"""Hostile and broken submissions: each is a 4xx JSON error naming the problem, and nothing
of it is stored (no file, no Redis key, no queue entry).

The property test at the end checks that the parameter checks made at submission cover the
solver's: whatever size-dependent parameters pass ``POST /v1/jobs`` run without the solver
refusing them or crashing.
"""

from __future__ import annotations

import io
import json
import pickle
import zipfile
from collections.abc import Callable, Iterator
from typing import Any

import h5py
import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from redis import Redis

from moju_core import reconstruct
from moju_core.datasets import make_sequence
from moju_core.errors import MeasurementError
from moju_core.params import SolverParams
from service.errors import InvalidInput
from service.settings import Settings
from service.uploads import check_params_fit

RNG = np.random.default_rng(7)
GOOD_W = RNG.normal(size=(8, 40))  # 4 frames, 40 points


def _npz(**arrays: Any) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _h5(build: Callable[[h5py.File], None]) -> bytes:
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as h5:
        build(h5)
    return buffer.getvalue()


def _csv(text: str) -> bytes:
    return text.encode()


def _pickled_npz() -> bytes:
    objects = np.empty((8, 40), dtype=object)
    objects[:] = 1.0
    return _npz(W=objects)


def _npz_with_raw_pickle() -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("W.npy", pickle.dumps(GOOD_W))
    return buffer.getvalue()


def _npz_with_lying_header(shape: tuple[int, ...] = (40, 1000)) -> bytes:
    """A member whose header promises far more data than it holds (a "zip bomb" of sorts)."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": shape}
    )
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("W.npy", header.getvalue() + b"\x00" * 64)
    return buffer.getvalue()


def _ragged_h5(h5: h5py.File) -> None:
    ragged = h5.create_dataset("W", (8,), dtype=h5py.vlen_dtype(np.float64))
    for row in range(8):
        ragged[row] = np.arange(row + 1, dtype=np.float64)


def _external_link_h5(h5: h5py.File) -> None:
    h5["W"] = h5py.ExternalLink("/etc/passwd", "/W")


def _soft_link_through_external_h5(h5: h5py.File) -> None:
    h5["elsewhere"] = h5py.ExternalLink("/etc/passwd", "/group")
    h5["W"] = h5py.SoftLink("/elsewhere/W")


def _fill_value_bomb_h5(h5: h5py.File) -> None:
    """2000 frames x 50000 points of fill value: a few kB on disk, 1.6 GB once read."""
    h5.create_dataset("W", shape=(4000, 50_000), dtype="f8", chunks=(100, 1000), fillvalue=1.0)


def _zeros_npz(shape: tuple[int, int]) -> bytes:
    """An npz of zeros, compressed while written (never held in memory uncompressed)."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": shape}
    )
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        with archive.open("W.npy", "w", force_zip64=True) as member:
            member.write(header.getvalue())
            row = bytes(8 * shape[1])
            for _ in range(shape[0]):
                member.write(row)
    return buffer.getvalue()


HUGE_INTEGER = "9" * 5000  # more digits than Python converts from text by default


def _tracks_csv(n_frames: int = 3, n_points: int = 4, broken: str | None = None) -> str:
    lines = ["frame,point,x,y"]
    for frame in range(n_frames):
        for point in range(n_points):
            lines.append(f"{frame},{point},{point + 0.1 * frame},{point * point - frame}")
    if broken == "cell":
        lines[2] = "0,1,abc,2.0"
    elif broken == "lonely point":  # point 3 keeps only its row of frame 0
        lines = [line for line in lines if not line.endswith(tuple(
            f",3,{3 + 0.1 * frame},{9 - frame}" for frame in (1, 2)))]  # fmt: skip
    return "\n".join(lines) + "\n"


def _file(content: bytes, name: str = "tracks.npz", params: Any = None) -> dict:
    data = {} if params is None else {"params": params if isinstance(params, str)
                                      else json.dumps(params)}  # fmt: skip
    return {"files": {"file": (name, content, "application/octet-stream")}, "data": data}


def _json_body(text: str) -> dict:
    return {"content": text.encode(), "headers": {"content-type": "application/json"}}


def _with_nan(W: np.ndarray, value: float) -> np.ndarray:
    broken = W.copy()
    broken[5, 7] = value
    return broken


# (case id, request builder, expected status, words the detail must contain)
CASES: list[tuple[str, Callable[[], dict], int, tuple[str, ...]]] = [
    ("npz of pickled objects", lambda: _file(_pickled_npz()), 422, ("never pickles",)),
    (
        "npz member that is a raw pickle",
        lambda: _file(_npz_with_raw_pickle()),
        422,
        ("could not read", "as npz"),
    ),
    (
        "npz header promising more than it holds",
        lambda: _file(_npz_with_lying_header()),
        422,
        ("truncated",),
    ),
    (
        "npz declaring a huge array",
        lambda: _file(_npz_with_lying_header((8, 10**9))),
        413,
        ("1000000000 points", "the limit is"),
    ),
    ("npz without W", lambda: _file(_npz(X=GOOD_W)), 422, ("no dataset named W or tracks",)),
    (
        "HDF5 W of strings",
        lambda: _file(
            _h5(lambda h5: h5.create_dataset("W", data=np.array([[b"1", b"2", b"3"]] * 4))), "w.h5"
        ),
        422,
        ("byte strings",),
    ),
    (
        "HDF5 W of complex numbers",
        lambda: _file(_h5(lambda h5: h5.create_dataset("W", data=GOOD_W.astype(complex))), "w.h5"),
        422,
        ("complex numbers",),
    ),
    ("HDF5 ragged W", lambda: _file(_h5(_ragged_h5), "w.h5"), 422, ("variable-length",)),
    (
        "HDF5 tracks of the wrong shape",
        lambda: _file(
            _h5(lambda h5: h5.create_dataset("tracks", data=np.zeros((4, 40, 3)))), "w.h5"
        ),
        422,
        ("tracks has shape (4, 40, 3)",),
    ),
    (
        "HDF5 R of the wrong shape",
        lambda: _file(
            _h5(
                lambda h5: (
                    h5.create_dataset("W", data=GOOD_W),
                    h5.create_dataset("R", data=np.zeros((4, 3, 3))),
                )
            ),
            "w.h5",
        ),
        422,
        ("R ",),
    ),
    (
        "HDF5 link to another file",
        lambda: _file(_h5(_external_link_h5), "w.h5"),
        422,
        ("link to another file",),
    ),
    (
        "HDF5 soft link that goes through a link to another file",
        lambda: _file(_h5(_soft_link_through_external_h5), "w.h5"),
        422,
        ("link to another file",),
    ),
    (
        "HDF5 of fill value needing more memory than a worker has",
        lambda: _file(_h5(_fill_value_bomb_h5), "w.h5"),
        413,
        ("2000 frames x 50000 points", "MOJU_WORKER_MEMORY_BYTES"),
    ),
    (
        "compressed npz of zeros needing more memory than a worker has",
        lambda: _file(_zeros_npz((4000, 2000))),
        413,
        ("2000 frames x 2000 points", "MOJU_WORKER_MEMORY_BYTES"),
    ),
    (
        "one-line CSV",
        lambda: _file(b"frame,point,x,y" + b",0" * 100_000, "t.csv"),
        422,
        ("line 1", "longer than 4096 bytes"),
    ),
    (
        "huge integer in the params field",
        lambda: _file(_npz(W=GOOD_W), params='{"max_iter": ' + HUGE_INTEGER + "}"),
        422,
        ("'params' field cannot be read",),
    ),
    (
        "huge integer in a JSON body",
        lambda: _json_body('{"tracks": [[[0, 0]]], "params": {"seed": ' + HUGE_INTEGER + "}}"),
        422,
        ("JSON body cannot be read",),
    ),
    (
        "huge but readable integer as a coordinate",
        lambda: _json_body('{"tracks": [[[0, ' + "9" * 400 + "]]]}"),
        422,
        ("tracks",),
    ),
    (
        "number given as a string",
        lambda: _file(_npz(W=GOOD_W), params={"max_iter": "5"}),
        422,
        ("parameter 'max_iter'", "valid integer"),
    ),
    (
        "boolean given as a number",
        lambda: _file(_npz(W=GOOD_W), params={"seed": True}),
        422,
        ("parameter 'seed'", "valid integer"),
    ),
    (
        "boolean given as a number in a JSON body",
        lambda: _json_body('{"tracks": [[[0, 0]]], "params": {"rho": true}}'),
        422,
        ("parameter 'rho'",),
    ),
    (
        "JSON body over its own limit",
        lambda: _json_body('{"tracks": [' + ",".join(["[[0.5, 0.5]]"] * 10_000) + "]}"),
        413,
        ("MOJU_MAX_JSON_BYTES", "npz"),
    ),
    (
        "truncated HDF5",
        lambda: _file(_h5(lambda h5: h5.create_dataset("W", data=GOOD_W))[:300], "w.h5"),
        422,
        ("could not read", "HDF5"),
    ),
    (
        "CSV without column y",
        lambda: _file(_csv("frame,point,x\n0,0,1\n"), "t.csv"),
        422,
        ("lacks column(s) y",),
    ),
    (
        "CSV with a non-numeric cell",
        lambda: _file(_csv(_tracks_csv(broken="cell")), "t.csv"),
        422,
        ("line 3", "'abc' is not a number"),
    ),
    (
        "CSV with a point in one frame only",
        lambda: _file(_csv(_tracks_csv(broken="lonely point")), "t.csv"),
        422,
        ("in fewer than 2 frames: point(s) 3", "drop these points"),
    ),
    (
        "CSV that is binary junk",
        lambda: _file(b"\xff\xfe\x00junk" * 10, "t.csv"),
        422,
        ("not valid UTF-8",),
    ),
    ("empty file", lambda: _file(b"", "t.csv"), 422, ("CSV header",)),
    (
        "NaN in W",
        lambda: _file(_npz(W=_with_nan(GOOD_W, np.nan))),
        422,
        ("one coordinate NaN", "frame 2, point 7"),
    ),
    (
        "infinity in W",
        lambda: _file(_npz(W=_with_nan(GOOD_W, -np.inf))),
        422,
        ("1 infinite", "frame 2, point 7"),
    ),
    (
        "NaN in JSON tracks",
        lambda: _json_body(
            '{"tracks": [[[0, 0], [1, 0], [0, 1]], [[NaN, 0], [1, 0], [0, 1]], '
            "[[0, 0], [1, 1], [0, 1]]]}"
        ),
        422,
        ("NaN",),
    ),
    (
        "coordinates near the float64 limit",
        lambda: _file(_npz(W=GOOD_W * 1e299)),
        422,
        ("as large as", "Rescale"),
    ),
    (
        "a PNG image as the file",
        lambda: _file(b"\x89PNG\r\n\x1a\n" + b"\x00" * 64, "frame.png"),
        422,
        ("PNG image", "video (mp4, webm or avi)", "'mask'"),
    ),
    (
        "an empty file named like a video",
        lambda: _file(b"", "clip.mp4"),
        422,
        ("clip.mp4 is named like a video but is empty",),
    ),
    (
        "binary junk without a CSV name",
        lambda: _file(b"\x00\x01\xff\xfe" * 20, "upload.bin"),
        422,
        ("not valid UTF-8", "video"),
    ),
    (
        "unknown parameter with a very long name",
        lambda: _file(_npz(W=GOOD_W), params={"x" * 5000: 1}),
        422,
        ("unknown parameter", "(5000 characters)"),
    ),
    (
        "W with an odd number of rows",
        lambda: _file(_npz(W=GOOD_W[:7])),
        422,
        ("7 rows", "even number"),
    ),
    ("one frame", lambda: _file(_npz(W=GOOD_W[:2])), 422, ("1 frame(s)", "at least 2")),
    (
        "two frames and rotations to estimate",
        lambda: _file(_npz(W=GOOD_W[:4])),
        422,
        ("needs at least 3 frames",),
    ),
    ("too few points", lambda: _file(_npz(W=GOOD_W[:, :2])), 422, ("2 point(s)",)),
    (
        "more groups than points",
        lambda: _file(_npz(W=GOOD_W), params={"n_groups": 50}),
        422,
        ("n_groups=50 needs at least", "the input has 40"),
    ),
    (
        "subspace dimension above 3F",
        lambda: _file(_npz(W=GOOD_W), params={"subspace_dim": 12}),
        422,
        ("subspace_dim=12", "3F = 12"),
    ),
    (
        "more shape bases than the frames allow",
        lambda: _file(_npz(W=GOOD_W), params={"n_bases": 3}),
        422,
        ("n_bases=3 needs at least 15 frames",),
    ),
    (
        "unknown parameter",
        lambda: _file(_npz(W=GOOD_W), params={"max_itr": 5}),
        422,
        ("unknown parameter 'max_itr'",),
    ),
    (
        "absurd iteration count",
        lambda: _file(_npz(W=GOOD_W), params={"max_iter": 10**12}),
        422,
        ("parameter 'max_iter'", "less than or equal to 10000"),
    ),
    (
        "negative tolerance",
        lambda: _file(_npz(W=GOOD_W), params={"tol": -1}),
        422,
        ("parameter 'tol'", "greater than or equal to 0"),
    ),
    (
        "NaN penalty",
        lambda: _file(_npz(W=GOOD_W), params='{"rho": NaN}'),
        422,
        ("parameter 'rho'",),
    ),
    (
        "shell command as a method",
        lambda: _file(_npz(W=GOOD_W), params={"method": "rm -rf /"}),
        422,
        ("parameter 'method'",),
    ),
    (
        "parameters that are not an object",
        lambda: _file(_npz(W=GOOD_W), params="[1, 2]"),
        422,
        ("params must be a JSON object",),
    ),
    (
        "deeply nested parameters",
        lambda: _file(_npz(W=GOOD_W), params="[" * 5000 + "]" * 5000),
        422,
        ("the 'params' field nests arrays or objects too deeply",),
    ),
    (
        "deeply nested JSON body",
        lambda: _json_body('{"tracks": ' + "[" * 30_000 + "]" * 30_000 + "}"),
        422,
        ("the JSON body nests",),
    ),
    (
        "wrong content type",
        lambda: {"content": b"W,1,2", "headers": {"content-type": "text/csv"}},
        415,
        ("unsupported content type 'text/csv'",),
    ),
    (
        "no content type",
        lambda: {"content": b"\x00" * 10},
        415,
        ("unsupported content type 'none'",),
    ),
    (
        "oversized body",
        lambda: _file(b"\x00" * (2 * 2**20)),
        413,
        ("at most 1048576 bytes", "MOJU_MAX_UPLOAD_BYTES"),
    ),
]


@pytest.fixture
def guarded(settings: Settings) -> Iterator:
    limited = settings.model_copy(
        update={
            "max_upload_bytes": 2**20,
            "max_json_bytes": 65536,
            "max_points": 50_000,
            "worker_memory_bytes": 2**30,
        }
    )
    from service.app import create_app

    with TestClient(create_app(limited)) as client:
        yield client, limited


@pytest.mark.parametrize(
    ("build", "status", "words"),
    [pytest.param(build, status, words, id=name) for name, build, status, words in CASES],
)
def test_refused_with_a_message_and_nothing_stored(
    guarded, redis_client: Redis, build, status: int, words: tuple[str, ...]
) -> None:
    client, limited = guarded
    response = client.post("/v1/jobs", **build())
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    body = response.json()
    assert set(body) == {"detail"} and isinstance(body["detail"], str)
    for word in words:
        assert word in body["detail"], (word, body["detail"])
    assert list((limited.data_dir / "jobs").iterdir()) == []
    assert redis_client.keys("*") == []  # no record, no queue entry, no slot


@pytest.mark.parametrize(
    "request_of",
    [
        pytest.param(lambda: ("GET", "/v1/" + "a" * 60_000, {}), id="60 kB path"),
        pytest.param(
            lambda: ("POST", "/v1/jobs", _file(_npz(W=GOOD_W), params={"y" * 5000: 1})),
            id="5000-character parameter name",
        ),
        pytest.param(
            lambda: ("POST", "/v1/jobs", {"files": {"z" * 5000: ("a", b"1")}}),
            id="5000-character form field",
        ),
    ],
)
def test_huge_names_are_not_echoed_whole(guarded, request_of) -> None:
    client, _ = guarded
    method, path, options = request_of()
    response = client.request(method, path, **options)
    assert 400 <= response.status_code < 500, response.text[:300]
    assert len(response.json()["detail"]) < 1500, len(response.json()["detail"])


def test_the_same_input_is_accepted_when_sound(guarded, redis_client: Redis) -> None:
    """The cases above fail for the reason given, not because the base input is broken."""
    client, limited = guarded
    response = client.post("/v1/jobs", **_file(_npz(W=GOOD_W), params={"max_iter": 5}))
    assert response.status_code == 202, response.text
    response = client.post("/v1/jobs", **_file(_csv(_tracks_csv()), "t.csv"))
    assert response.status_code == 202, response.text
    assert len(list((limited.data_dir / "jobs").iterdir())) == 2


# ------------------------------------------------------------------------------------------
# Submission-time parameter checks cover the solver's own


@pytest.fixture(scope="module")
def tiny_face() -> np.ndarray:
    return make_sequence("face1", n_points=120).W  # 10 frames


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    n_frames=st.integers(2, 6),
    n_points=st.integers(3, 120),
    method=st.sampled_from(["moju", "sdg", "bmm"]),
    rotations=st.sampled_from(["intersection", "rigid", None]),
    n_groups=st.one_of(st.none(), st.integers(1, 8)),
    subspace_dim=st.one_of(st.none(), st.integers(1, 20)),
    n_bases=st.one_of(st.none(), st.integers(1, 3)),
)
# Known edges, always tried: a local subspace wider than a trajectory (the solver's
# eigen-decomposition fails on it), groups that just fill the points, rigid with 3 frames.
@example(n_frames=3, n_points=60, method="moju", rotations=None, n_groups=2, subspace_dim=10,
         n_bases=None)  # fmt: skip
@example(n_frames=4, n_points=64, method="sdg", rotations="rigid", n_groups=4, subspace_dim=8,
         n_bases=None)  # fmt: skip
@example(n_frames=3, n_points=3, method="bmm", rotations="rigid", n_groups=None,
         subspace_dim=None, n_bases=None)  # fmt: skip
def test_parameters_accepted_at_submission_run(
    tiny_face, n_frames, n_points, method, rotations, n_groups, subspace_dim, n_bases
) -> None:
    chosen = {"method": method, "n_groups": n_groups, "subspace_dim": subspace_dim,
              "n_bases": n_bases, "rotations": rotations, "max_iter": 2}  # fmt: skip
    params = SolverParams(**{k: v for k, v in chosen.items() if v is not None})
    W = tiny_face[: 2 * n_frames, :n_points]
    try:
        check_params_fit(params, n_frames, n_points, has_rotations=False)
    except InvalidInput:
        return  # refused at submission: the solver never sees it
    try:
        reconstruct(W, params)
    except MeasurementError as exc:
        # Only refusals about the data itself may remain for the worker to report.
        assert "zero after centring" in str(exc) or "rank" in str(exc), str(exc)
