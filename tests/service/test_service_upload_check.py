"""Uploads are checked in a child process: the API never holds their arrays, the child's
memory is capped, and the number of checks at once is bounded.

Memory is counted with ``tracemalloc`` in the test process, which runs the app under
``TestClient``: what the request made Python and numpy allocate here, not timings.
"""

from __future__ import annotations

import http.client
import io
import json
import os
import signal
import tempfile
import threading
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from api_thread import serving
from fastapi.testclient import TestClient

from service import uploads
from service.app import create_app
from service.check_process import run_check
from service.errors import InvalidInput, UploadTooLarge
from service.settings import Settings

MIB = 2**20


@pytest.fixture
def private_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A temporary directory of the test's own, so that leftovers can be counted."""
    directory = tmp_path / "tmp"
    directory.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(directory))
    return directory


def _leftovers(directory: Path) -> list[str]:
    """Temporary entries of uploads (not the fork server's own socket directory, pymp-*)."""
    return [path.name for path in directory.iterdir() if not path.name.startswith("pymp-")]


def _npz(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _moving_W(n_frames: int, n_points: int) -> np.ndarray:
    rng = np.random.default_rng(3)
    shape = rng.normal(size=(3, n_points))
    rows = [rng.normal(size=(2, 3)) @ shape for _ in range(n_frames)]
    return np.vstack(rows)


def _post_file(url: str, part: bytes, directory: Path) -> tuple[int, dict]:
    """POST a multipart body from a file on disk (http.client sends it in 8 KiB blocks)."""
    boundary = "moju-test-boundary"
    body = directory / "body"
    with open(body, "wb") as out:
        out.write(
            f'--{boundary}\r\nContent-Disposition: form-data; name="file"; '
            'filename="w.npz"\r\nContent-Type: application/octet-stream\r\n\r\n'.encode()
        )
        out.write(part)
        out.write(f"\r\n--{boundary}--\r\n".encode())
    host, port = url.removeprefix("http://").split(":")
    connection = http.client.HTTPConnection(host, int(port), timeout=120)
    try:
        with open(body, "rb") as handle:
            connection.request(
                "POST",
                "/v1/jobs",
                body=handle,
                headers={
                    "Content-Type": f"multipart/form-data; boundary={boundary}",
                    "Content-Length": str(body.stat().st_size),
                },
            )
        response = connection.getresponse()
        return response.status, json.loads(response.read())
    finally:
        connection.close()


def test_accepted_upload_arrays_are_not_allocated_in_the_api(
    settings: Settings, private_tmp: Path, tmp_path: Path
) -> None:
    W = _moving_W(100, 10_000)  # 16 MB of float64
    part = _npz(W=W)
    with serving(settings) as url:
        tracemalloc.start()
        try:
            status, answer = _post_file(url, part, tmp_path)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert status == 202, answer
    assert answer["input"]["frames"] == 100
    # Reading W in this process would take 16 MB at least (and the npz's bytes another 16).
    assert peak < 6 * MIB, f"{peak / MIB:.1f} MiB"
    assert _leftovers(private_tmp) == []  # the staged files were moved in or removed


def test_upload_needing_more_than_the_check_memory_is_413(
    settings: Settings, private_tmp: Path
) -> None:
    capped = settings.model_copy(update={"upload_check_memory_bytes": 64 * MIB})
    W = np.zeros((2000, 10_000))  # 160 MB once read, 0.2 MB compressed
    buffer = io.BytesIO()
    np.savez_compressed(buffer, W=W)
    files = {"file": ("zeros.npz", buffer.getvalue(), "application/octet-stream")}
    with TestClient(create_app(capped)) as client:
        answer = client.post("/v1/jobs", files=files)
    assert answer.status_code == 413, answer.text
    assert "MOJU_UPLOAD_CHECK_MEMORY_BYTES" in answer.json()["detail"]
    assert _leftovers(private_tmp) == []
    assert list((settings.data_dir / "jobs").iterdir()) == []


def test_checks_at_once_are_bounded(settings: Settings, monkeypatch: pytest.MonkeyPatch) -> None:
    bounded = settings.model_copy(update={"upload_checks": 2})
    running, most, lock = [0], [0], threading.Lock()
    real_run_check = uploads.run_check

    def counting(*args, **kwargs):
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        try:
            return real_run_check(*args, **kwargs)
        finally:
            with lock:
                running[0] -= 1

    monkeypatch.setattr(uploads, "run_check", counting)
    body = _npz(W=_moving_W(10, 8000))  # 1.3 MB: over what is checked in the API itself
    answers = []
    with TestClient(create_app(bounded)) as client:

        def submit() -> None:
            files = {"file": ("w.npz", body, "application/octet-stream")}
            answers.append(client.post("/v1/jobs", files=files).status_code)

        threads = [threading.Thread(target=submit) for _ in range(6)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    assert answers == [202] * 6
    assert 1 <= most[0] <= 2


def _die(_: object) -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _allocate(n_bytes: int) -> int:
    return int(np.ones(n_bytes // 8).sum())


def test_a_child_that_dies_is_a_422() -> None:
    with pytest.raises(InvalidInput, match="ended abruptly"):
        run_check(_die, None, memory_bytes=256 * MIB, timeout=60)


def test_the_child_memory_cap_holds() -> None:
    assert run_check(_allocate, 16 * MIB, memory_bytes=256 * MIB, timeout=60) == 2 * MIB
    with pytest.raises(UploadTooLarge, match="MOJU_UPLOAD_CHECK_MEMORY_BYTES"):
        run_check(_allocate, 512 * MIB, memory_bytes=128 * MIB, timeout=60)


def test_small_uploads_are_checked_without_a_child_process(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A small npz or JSON body is checked in the API's thread; an HDF5 or CSV file, of any
    size, and an npz whose members declare much data go to a child process."""
    children = []
    real_run_check = uploads.run_check

    def counting(function, check, **kwargs):
        children.append(check.kind)
        return real_run_check(function, check, **kwargs)

    monkeypatch.setattr(uploads, "run_check", counting)
    W = _moving_W(10, 300)
    zeros = io.BytesIO()
    np.savez_compressed(zeros, W=np.vstack([W, np.zeros((400, 300))]))  # 0.1 MB, 1 MB inside
    csv = "frame,point,x,y\n" + "".join(
        f"{f},{j},{W[2 * f, j]},{W[2 * f + 1, j]}\n" for f in range(10) for j in range(300)
    )
    with TestClient(create_app(settings)) as client:
        for name, content in (("w.npz", _npz(W=W)), ("t.csv", csv.encode())):
            files = {"file": (name, content, "application/octet-stream")}
            assert client.post("/v1/jobs", files=files).status_code == 202
        tracks = W.reshape(10, 2, 300).transpose(0, 2, 1).tolist()
        assert client.post("/v1/jobs", json={"tracks": tracks}).status_code == 202
        assert children == ["csv"]
        monkeypatch.setattr(uploads, "SMALL_ARRAY_BYTES", 2**19)
        files = {"file": ("z.npz", zeros.getvalue(), "application/octet-stream")}
        client.post("/v1/jobs", files=files)
    assert children == ["csv", "npz"]
