"""Slow and idle clients: 2,000 connections that never finish a request are all closed by the
server, while /healthz keeps answering.

The API runs as ``moju serve`` runs it (``python -m service.uvicorn_server``) with short
limits (3 s to send headers, 100 bytes/s for a body after 1 s, 1 s idle), so that the test
counts closed connections rather than waiting out the production defaults.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import resource
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from service_testing import REPO_ROOT, worker_environment

from service.processes import free_port, stop_process
from service.settings import Settings

CONNECTIONS = 2000
TRICKLE_SECONDS = 0.5
#: Only a safety net: the limits close everything within a few seconds.
GIVE_UP_SECONDS = 90.0


@pytest.fixture
def many_descriptors() -> Iterator[None]:
    """Room for 2,000 sockets here and in the API (which inherits the limit)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    wanted = 3 * CONNECTIONS
    if hard != resource.RLIM_INFINITY and hard < wanted:
        pytest.skip(f"the open-file limit is {hard}; this test needs {wanted}")
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, wanted), hard))
    yield
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


@pytest.fixture
def guarded_api(settings: Settings, tmp_path: Path, many_descriptors: None) -> Iterator[str]:
    port = free_port()
    env = worker_environment(
        settings,
        MOJU_HEADER_TIMEOUT="3",
        MOJU_MIN_BODY_RATE="100",
        MOJU_BODY_RATE_GRACE="1",
        MOJU_IDLE_TIMEOUT="1",
        MOJU_CLEANUP_INTERVAL="0",
    )
    command = [sys.executable, "-m", "service.uvicorn_server", "--port", str(port)]
    command += ["--log-level", "warning"]
    log_path = tmp_path / "api.log"
    with open(log_path, "wb") as log:
        process = subprocess.Popen(
            command, env=env, cwd=REPO_ROOT, stdout=log, stderr=subprocess.STDOUT
        )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{url}/healthz", timeout=2).status_code == 200:
                    break
            assert process.poll() is None, log_path.read_text()
            assert time.monotonic() < deadline, log_path.read_text()
            time.sleep(0.1)
        yield url
    finally:
        stop_process(process, timeout=10)


async def _slow_client(port: int, kind: str) -> bytes:
    """Open one connection that never completes its request; return what the server sent
    before it closed the connection."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    if kind == "headers":
        trickle = b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 10_000
    elif kind == "body":
        writer.write(
            b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000\r\n"
            b"Content-Type: multipart/form-data; boundary=b\r\n\r\n"
        )
        trickle = b"--b\r\n" + b"x" * 10_000
    else:  # idle: connects and sends nothing
        trickle = b""
    received = bytearray()

    async def read_until_closed() -> None:
        with contextlib.suppress(ConnectionError):
            while chunk := await reader.read(65536):
                received.extend(chunk)

    reading = asyncio.create_task(read_until_closed())
    with contextlib.suppress(ConnectionError):
        for byte in trickle:
            if reading.done():
                break
            writer.write(bytes([byte]))
            await asyncio.sleep(TRICKLE_SECONDS)
    await reading
    writer.close()
    return bytes(received)


async def _health_checks(url: str, stop: asyncio.Event) -> list[int]:
    statuses = []
    # A new connection each time: with a 1 s idle timeout, a kept-alive one may be closed by
    # the server just as the next check goes out.
    limits = httpx.Limits(max_keepalive_connections=0)
    async with httpx.AsyncClient(timeout=30, limits=limits) as client:
        while not stop.is_set():
            statuses.append((await client.get(f"{url}/healthz")).status_code)
            await asyncio.sleep(0.2)
    return statuses


async def _siege(url: str) -> tuple[dict[str, list[bytes]], list[int]]:
    port = int(url.rsplit(":", 1)[1])
    kinds = ["idle", "headers", "body"]
    stop = asyncio.Event()
    checks = asyncio.create_task(_health_checks(url, stop))
    clients = []
    for index in range(CONNECTIONS):
        kind = kinds[index % len(kinds)]
        clients.append((kind, asyncio.create_task(_slow_client(port, kind))))
        if index % 200 == 199:
            await asyncio.sleep(0)  # let the server accept as we go
    done, pending = await asyncio.wait([task for _, task in clients], timeout=GIVE_UP_SECONDS)
    stop.set()
    for task in pending:
        task.cancel()
    answers: dict[str, list[bytes]] = {kind: [] for kind in kinds}
    for kind, task in clients:
        if task in done:
            answers[kind].append(task.result())
    return answers, await checks


def test_two_thousand_slow_connections_are_closed_and_healthz_answers(guarded_api: str) -> None:
    answers, health = asyncio.run(_siege(guarded_api))
    closed = sum(len(found) for found in answers.values())
    assert closed == CONNECTIONS, {kind: len(found) for kind, found in answers.items()}
    # Idle and header tricklers are closed without an answer; trickled bodies get a 408.
    assert all(found == b"" for found in answers["idle"] + answers["headers"])
    assert all(found.startswith(b"HTTP/1.1 408 ") for found in answers["body"])
    assert b"MOJU_MIN_BODY_RATE" in answers["body"][0]
    assert health and set(health) == {200}
    with httpx.Client() as client:
        assert client.get(f"{guarded_api}/healthz").status_code == 200


def _npz_bytes(n_points: int) -> bytes:
    rng = np.random.default_rng(4)
    shape = rng.normal(size=(3, n_points))
    W = np.vstack([rng.normal(size=(2, 3)) @ shape for _ in range(6)])
    buffer = io.BytesIO()
    np.savez(buffer, W=W)
    return buffer.getvalue()


def _multipart(part: bytes) -> tuple[bytes, str]:
    boundary = "slow-clients-test"
    body = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="w.npz"\r\n'
        "Content-Type: application/octet-stream\r\n\r\n"
    ).encode()
    return body + part + f"\r\n--{boundary}--\r\n".encode(), boundary


def test_uploads_of_every_size_pass_the_guard(guarded_api: str) -> None:
    """Bodies under and over the 64 KiB the app waits for, and a client that waits for
    '100 Continue' before sending its body (as curl does above 1 MB), are all read."""
    for n_points in (50, 2000):  # about 5 kB and 100 kB of npz
        files = {"file": ("w.npz", _npz_bytes(n_points), "application/octet-stream")}
        answer = httpx.post(f"{guarded_api}/v1/jobs", files=files, timeout=60)
        assert answer.status_code == 202, answer.text
    body, boundary = _multipart(_npz_bytes(2000))
    port = int(guarded_api.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=60) as connection:
        connection.sendall(
            f"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nExpect: 100-continue\r\n"
            f"Content-Type: multipart/form-data; boundary={boundary}\r\n"
            f"Content-Length: {len(body)}\r\n\r\n".encode()
        )
        assert connection.recv(1024).startswith(b"HTTP/1.1 100 ")
        connection.sendall(body)
        answer = b""
        while b"\r\n\r\n" not in answer:
            answer += connection.recv(65536)
    assert answer.startswith(b"HTTP/1.1 202 "), answer[:300]
