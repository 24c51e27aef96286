"""Admission before reading: refused uploads cost little memory; stalled and aborted bodies.

Memory is measured with ``tracemalloc`` around the request (the app runs in the test process
under ``TestClient``; numpy reports its buffers to tracemalloc), so the figures are the bytes
the request made Python and numpy allocate, independent of the machine's speed.
"""

from __future__ import annotations

import io
import json
import logging
import os
import socket
import tempfile
import time
import tracemalloc
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np
import pytest
from api_thread import serving
from fastapi.testclient import TestClient
from test_service_hostile_input import _fill_value_bomb_h5, _h5, _zeros_npz

from moju_core.errors import MeasurementTooLarge
from moju_core.io import read_measurements
from service.app import create_app
from service.settings import Settings

MIB = 2**20


@pytest.fixture
def admitting(settings: Settings) -> Iterator[TestClient]:
    # The default limits: 2000 frames, 50000 points, 8 GiB of worker memory, 256 MiB bodies.
    with TestClient(create_app(settings)) as client:
        yield client


def _refusing():
    def refuse(n_frames: int, n_points: int) -> None:
        raise MeasurementTooLarge(f"{n_frames} x {n_points} refused")

    return refuse


def _peak_of(send) -> tuple[object, int]:
    tracemalloc.start()
    try:
        answer = send()
        return answer, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_npz_of_zeros_is_refused_from_its_headers(admitting: TestClient) -> None:
    # 2000 frames x 50000 points of zeros: 800 MB of float64 in a 0.8 MB file.
    bomb = _zeros_npz((4000, 25_000))
    files = {"file": ("bomb.npz", bomb, "application/octet-stream")}
    answer, peak = _peak_of(lambda: admitting.post("/v1/jobs", files=files))
    assert answer.status_code == 413, answer.text
    assert "MOJU_WORKER_MEMORY_BYTES" in answer.json()["detail"]
    assert peak < 20 * MIB, f"{peak / MIB:.0f} MiB"


def test_hdf5_of_fill_value_is_refused_from_its_metadata(admitting: TestClient) -> None:
    files = {"file": ("bomb.h5", _h5(_fill_value_bomb_h5), "application/octet-stream")}
    answer, peak = _peak_of(lambda: admitting.post("/v1/jobs", files=files))
    assert answer.status_code == 413, answer.text
    assert "2000 frames x 50000 points" in answer.json()["detail"]
    assert peak < 20 * MIB, f"{peak / MIB:.0f} MiB"


def test_csv_is_refused_from_its_row_count_before_w_is_built(
    settings: Settings, tmp_path: Path
) -> None:
    small = settings.model_copy(update={"worker_memory_bytes": 256 * MIB})
    # 1000 frames x 1000 points = 10^6 rows: 256 MB + 128 MiB estimated, over 256 MiB.
    frames, points = np.divmod(np.arange(10**6), 1000)
    path = tmp_path / "t.csv"
    with open(path, "w") as out:
        out.write("frame,point,x,y\n")
        np.savetxt(out, np.column_stack([frames, points, points, frames]), fmt="%d", delimiter=",")
    with TestClient(create_app(small)) as client, open(path, "rb") as handle:
        files = {"file": ("t.csv", handle, "text/csv")}
        answer = client.post("/v1/jobs", files=files)
    assert answer.status_code == 413, answer.text
    assert "1000 frames x 1000 points" in answer.json()["detail"]
    assert "MOJU_WORKER_MEMORY_BYTES" in answer.json()["detail"]
    # TestClient holds the whole request in memory, so the reader's own peak is measured
    # without it.
    refuse = _refusing()
    tracemalloc.start()
    try:
        with pytest.raises(MeasurementTooLarge, match="1000 x 1000 refused"):
            read_measurements(path, admit=refuse)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # W alone would be 16 MB and the rows as one table 32 MB; a block of rows is far less.
    assert peak < 24 * MIB, f"{peak / MIB:.0f} MiB"


def test_json_body_over_its_limit_is_refused_before_it_is_read(settings: Settings) -> None:
    capped = settings.model_copy(update={"max_json_bytes": MIB})
    body = json.dumps({"tracks": [[[0.5, 0.5]] * 1000] * 200}).encode()  # 2.8 MB
    with TestClient(create_app(capped)) as client:
        answer, peak = _peak_of(
            lambda: client.post(
                "/v1/jobs", content=body, headers={"content-type": "application/json"}
            )
        )
    assert answer.status_code == 413
    assert "at most 1048576 bytes" in answer.json()["detail"]
    assert "MOJU_MAX_JSON_BYTES" in answer.json()["detail"]
    assert peak < 8 * MIB, f"{peak / MIB:.0f} MiB"


def test_params_sent_as_a_file_part_are_read(admitting: TestClient, input_file: Path) -> None:
    files = {
        "file": ("t.npz", input_file.read_bytes(), "application/octet-stream"),
        "params": ("params.json", b'{"max_iter": 7}', "application/json"),
    }
    answer = admitting.post("/v1/jobs", files=files)
    assert answer.status_code == 202, answer.text
    assert answer.json()["parameters"]["max_iter"] == 7


# ------------------------------------------------------------------------------------------
# Bodies that stall or are abandoned (a real server over real sockets)


def _spooled_files() -> int:
    """Open files of this process in the temporary directory (starlette's spooled uploads)."""
    root = tempfile.gettempdir()
    count = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            if os.readlink(f"/proc/self/fd/{fd}").startswith(root):
                count += 1
        except OSError:
            continue
    return count


def _stalled_upload(url: str, sent_bytes: int, announced: int) -> socket.socket:
    host, port = url.removeprefix("http://").split(":")
    boundary = "stall"
    head = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="w.npz"\r\n'
        "Content-Type: application/octet-stream\r\n\r\n"
    ).encode()
    connection = socket.create_connection((host, int(port)), timeout=60)
    connection.sendall(
        (
            f"POST /v1/jobs HTTP/1.1\r\nHost: {host}\r\nContent-Length: {announced}\r\n"
            f"Content-Type: multipart/form-data; boundary={boundary}\r\n\r\n"
        ).encode()
        + head
        + b"\x00" * sent_bytes
    )
    return connection


def _wait_until(condition, what: str, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="counts open files in /proc")
def test_stalled_body_gets_408_and_its_spool_file_is_removed(settings: Settings) -> None:
    quick = settings.model_copy(update={"body_timeout": 1.0})
    before = _spooled_files()
    with serving(quick) as url:
        connection = _stalled_upload(url, sent_bytes=3 * MIB, announced=100 * MIB)
        try:
            # The upload spooled to disk (over 1 MiB), then stopped.
            _wait_until(lambda: _spooled_files() > before, "the spooled upload")
            answer = b""
            while chunk := connection.recv(65536):  # the server closes the connection
                answer += chunk
            answer = answer.decode(errors="replace")
            assert answer.startswith("HTTP/1.1 408"), answer
            assert "MOJU_BODY_TIMEOUT" in answer
            _wait_until(lambda: _spooled_files() == before, "the spool file to be removed")
        finally:
            connection.close()
        assert not list((quick.data_dir / "jobs").iterdir())


def test_client_that_goes_away_is_one_log_line(settings: Settings, caplog) -> None:
    caplog.set_level(logging.INFO)
    with serving(settings) as url:
        connection = _stalled_upload(url, sent_bytes=64 * 1024, announced=10 * MIB)
        connection.close()
        _wait_until(
            lambda: any("client went away" in r.getMessage() for r in caplog.records),
            "the disconnect to be logged",
        )
    gone = [r for r in caplog.records if "client went away" in r.getMessage()]
    assert len(gone) == 1 and gone[0].exc_info is None
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"


def test_h5_bytes_are_not_materialised_for_a_refused_file() -> None:
    """The HDF5 reader builds no array for a dataset it refuses (library level)."""
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as h5:
        _fill_value_bomb_h5(h5)
    refuse = _refusing()
    tracemalloc.start()
    try:
        with pytest.raises(MeasurementTooLarge, match="2000 x 50000 refused"):
            read_measurements(io.BytesIO(buffer.getvalue()), admit=refuse)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * MIB


def test_json_body_is_parsed_off_the_event_loop(
    admitting: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A small body is parsed in a worker thread, a large one (over 1 MiB) in the check's
    child process: never on the event loop, and a large one never in the API process."""
    import asyncio

    real_loads, on_loop = json.loads, []

    def loads(text, *args, **kwargs):
        try:
            asyncio.get_running_loop()
            on_loop.append((True, len(text)))
        except RuntimeError:  # no event loop in this thread
            on_loop.append((False, len(text)))
        return real_loads(text, *args, **kwargs)

    monkeypatch.setattr(json, "loads", loads)
    rng = np.random.default_rng(1)
    small = json.dumps({"tracks": rng.normal(size=(4, 30, 2)).tolist(), "params": {"max_iter": 5}})
    large = json.dumps({"tracks": rng.normal(size=(4, 8000, 2)).tolist()})
    assert len(large) > 2**20
    for body in (small, large):
        answer = admitting.post(
            "/v1/jobs", content=body, headers={"content-type": "application/json"}
        )
        assert answer.status_code == 202, answer.text[:300]
    assert on_loop == [(False, len(small))]
