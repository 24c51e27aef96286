"""Faults with real processes: workers killed with SIGKILL, Redis restarted, jobs cancelled.

Each test runs real ``python -m worker`` processes (RQ's forking worker) against a real
``redis-server``. The heartbeat settings are short (0.5 s beats, a 2 s lease) so that a lost
worker is noticed in seconds; they are ordinary settings (``MOJU_HEARTBEAT_INTERVAL``,
``MOJU_HEARTBEAT_TTL``), the same code path as the defaults (5 s, 30 s).
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from redis import Redis
from rq.job import Job as RQJob
from service_testing import (
    LONG_PARAMS,
    measurements_of,
    running_worker,
    wait_for,
)
from threadpoolctl import threadpool_limits

from moju_core import reconstruct
from moju_core.io import read_result, write_measurements
from moju_core.params import SolverParams
from service.app import create_app
from service.job_store import JobStore
from service.processes import children_of
from service.redis_server import RedisServer, find_redis_server
from service.settings import Settings
from service.storage import INPUT_NAME

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/stat").exists(), reason="finds work horses through Linux /proc"
)

#: A few seconds of work on the 300-point face: long enough to be killed mid-way.
MEDIUM_PARAMS = {"max_iter": 1500, "tol": 0.0, "rho_growth": 1.01, "rho_max": 1e12}
#: What a work horse killed while writing its result would leave in the job's directory.
HALF_WRITTEN = ".result.h5.0123456789ab.tmp"


@pytest.fixture
def fast_settings(settings: Settings) -> Settings:
    """Heartbeats every 0.5 s, a worker counts as lost after 2 s without one."""
    return settings.model_copy(update={"heartbeat_interval": 0.5, "heartbeat_ttl": 2.0})


def _submit_file(client: TestClient, path: Path, params: dict) -> str:
    files = {"file": (path.name, path.read_bytes())}
    response = client.post("/v1/jobs", files=files, data={"params": json.dumps(params)})
    assert response.status_code == 202, response.text
    return response.json()["id"]


def _iterating(client: TestClient, job_id: str, at_least: int = 3) -> bool:
    job = client.get(f"/v1/jobs/{job_id}").json()
    progress = job["progress"] or {}
    return job["status"] == "running" and progress.get("iteration", 0) >= at_least


def _kill_worker_and_horse(pid: int) -> float:
    """SIGKILL a worker and its work horse (as the kernel's OOM killer would take a
    container); return the time of the kill."""
    horses = wait_for(lambda: children_of(pid), timeout=10, message="the work horse")
    os.kill(pid, signal.SIGKILL)
    for horse in horses:
        os.kill(horse, signal.SIGKILL)
    return time.monotonic()


def _raw_status(redis_url: str, job_id: str) -> str | None:
    """The stored status, read without any reconciliation: what the watchdog wrote."""
    connection = Redis.from_url(redis_url)
    try:
        value = connection.hget(f"moju:job:{job_id}", "status")
    finally:
        connection.close()
    return value.decode() if value else None


def test_killed_worker_fails_its_job_as_worker_lost(
    fast_settings: Settings,
    long_sequence,
    tmp_path: Path,
    record_property,
) -> None:
    settings = fast_settings.model_copy(update={"lost_job_retries": 0})
    path = write_measurements(tmp_path / "long.npz", measurements_of(long_sequence, extras=False))
    with TestClient(create_app(settings)) as client:
        with running_worker(settings, tmp_path / "worker.log") as worker:
            job_id = _submit_file(client, path, LONG_PARAMS)
            wait_for(lambda: _iterating(client, job_id), timeout=60, message="iterations")
            job_dir = settings.data_dir / "jobs" / job_id
            (job_dir / HALF_WRITTEN).write_bytes(b"\x89HDF\r\n\x1a\n half a result")
            killed_at = _kill_worker_and_horse(worker.process.pid)

            # Nobody reads the job: the API's watchdog alone must notice.
            wait_for(
                lambda: _raw_status(settings.redis_url, job_id) != "running",
                timeout=120,
                interval=0.05,
                message="the job to leave 'running'",
            )
            detected = time.monotonic() - killed_at
            failed = client.get(f"/v1/jobs/{job_id}").json()
            download = client.get(f"/v1/jobs/{job_id}/result")
    record_property("worker_lost_detection_seconds", round(detected, 2))
    print(f"\nworker lost -> failed after {detected:.2f} s (heartbeat TTL 2 s, beats 0.5 s)")
    assert detected < settings.heartbeat_ttl + 3 * settings.heartbeat_interval + 2.0
    assert failed["status"] == "failed" and failed["attempts"] == 1
    assert failed["error"].startswith("worker lost: the worker that took this job went away")
    assert failed["ended_at"] is not None
    # Only the input is left: no result, no half-written file.
    assert sorted(p.name for p in job_dir.iterdir()) == [INPUT_NAME]
    assert download.status_code == 409 and "worker lost" in download.json()["detail"]


def test_killed_worker_job_is_retried_on_another_worker_and_finishes(
    fast_settings: Settings,
    input_file: Path,
    small_sequence,
    tmp_path: Path,
    record_property,
) -> None:
    settings = fast_settings.model_copy(update={"lost_job_retries": 1})
    with TestClient(create_app(settings)) as client:
        with (
            running_worker(settings, tmp_path / "a.log") as first,
            running_worker(settings, tmp_path / "b.log") as second,
        ):
            job_id = _submit_file(client, input_file, MEDIUM_PARAMS)
            wait_for(lambda: _iterating(client, job_id), timeout=60, message="iterations")
            busy = wait_for(
                lambda: [w for w in (first, second) if children_of(w.process.pid)],
                timeout=10,
                message="the busy worker",
            )[0]
            idle = second if busy is first else first
            job_dir = settings.data_dir / "jobs" / job_id
            (job_dir / HALF_WRITTEN).write_bytes(b"\x89HDF\r\n\x1a\n half a result")
            killed_at = _kill_worker_and_horse(busy.process.pid)

            wait_for(
                lambda: _raw_status(settings.redis_url, job_id) != "running",
                timeout=120,
                interval=0.05,
                message="the job to be taken from the lost worker",
            )
            detected = time.monotonic() - killed_at
            finished = wait_for(
                lambda: (
                    (r := client.get(f"/v1/jobs/{job_id}").json())["status"]
                    in ("finished", "failed")
                    and r
                ),
                timeout=120,
                message="the retried job to end",
            )
            idle_log = idle.log()
            result_path = tmp_path / "result.npz"
            response = client.get(f"/v1/jobs/{job_id}/result", params={"format": "npz"})
            result_path.write_bytes(response.content)
            names = sorted(p.name for p in job_dir.iterdir())
    record_property("worker_lost_requeue_seconds", round(detected, 2))
    print(f"\nworker lost -> queued again after {detected:.2f} s (heartbeat TTL 2 s)")
    assert detected < settings.heartbeat_ttl + 3 * settings.heartbeat_interval + 2.0
    assert finished["status"] == "finished", finished["error"]
    assert finished["attempts"] == 2
    assert finished["result"]["n_iter"] == MEDIUM_PARAMS["max_iter"]
    assert f"job {job_id}: started (attempt 2," in idle_log
    # The stored result is the solver's, complete; nothing of the lost attempt is left.
    assert names == [INPUT_NAME, "result.h5", "result.npz"]
    with threadpool_limits(limits=1):
        expected = reconstruct(
            small_sequence.W,
            SolverParams(**MEDIUM_PARAMS),
            rotations=small_sequence.rotations,
        )
    with np.load(result_path) as npz:
        np.testing.assert_allclose(npz["shapes"], expected.shapes, rtol=0, atol=1e-9)
    assert read_result(result_path).metadata["job_id"] == job_id


def test_cancelling_queued_and_running_jobs_frees_the_worker(
    settings: Settings, long_sequence, small_sequence, tmp_path: Path, redis_client: Redis
) -> None:
    path = write_measurements(tmp_path / "long.npz", measurements_of(long_sequence, extras=False))
    small = write_measurements(tmp_path / "small.npz", measurements_of(small_sequence))
    with TestClient(create_app(settings)) as client:
        with running_worker(settings, tmp_path / "worker.log") as worker:
            running = _submit_file(client, path, LONG_PARAMS)
            wait_for(lambda: _iterating(client, running), timeout=60, message="iterations")
            queued = _submit_file(client, small, {"max_iter": 20})  # behind the long one
            assert client.get(f"/v1/jobs/{queued}").json()["status"] == "queued"

            assert client.delete(f"/v1/jobs/{queued}").status_code == 204
            assert client.delete(f"/v1/jobs/{running}").status_code == 204
            after = _submit_file(client, small, {"max_iter": 20})
            done = wait_for(
                lambda: (r := client.get(f"/v1/jobs/{after}").json())["status"] == "finished" and r,
                timeout=60,
                message="the next job to finish",
            )
            cancelled = {job: client.get(f"/v1/jobs/{job}").json() for job in (queued, running)}
            log = worker.log()
    assert done["attempts"] == 1
    for job in cancelled.values():
        assert job["status"] == "cancelled" and job["ended_at"] is not None
        assert not (settings.data_dir / "jobs" / job["id"]).exists()
    # The queued job never ran; RQ took it out of its queue.
    assert cancelled[queued]["started_at"] is None and cancelled[queued]["attempts"] == 0
    assert f"job {queued}: started" not in log
    assert RQJob.fetch(queued, connection=redis_client).get_status() == "canceled"
    # The running one stopped at an iteration and its worker went on to the next job.
    assert cancelled[running]["progress"]["iteration"] < LONG_PARAMS["max_iter"]
    assert f"job {running}: stopped, it is cancelled" in log
    assert JobStore(redis_client, retention_seconds=1).active_count("") == 0


def test_queued_jobs_survive_a_redis_restart_and_the_api_recovers(
    tmp_path: Path, small_sequence
) -> None:
    """Append-only persistence as in docker-compose.yml; 503 while Redis is down."""
    persistence = tmp_path / "redis"
    server = RedisServer(persistence_dir=persistence, binary=find_redis_server(prefer_path=True))
    server.start()
    try:
        settings = Settings(redis_url=server.url, data_dir=tmp_path / "data", cleanup_interval=0)
        small = write_measurements(tmp_path / "small.npz", measurements_of(small_sequence))
        with TestClient(create_app(settings)) as client:
            queued = [_submit_file(client, small, {"max_iter": 20, "seed": s}) for s in (1, 2)]

            server.stop()  # SIGTERM: Redis writes its append-only file and exits
            response = client.get(f"/v1/jobs/{queued[0]}")
            assert response.status_code == 503
            assert response.json() == {
                "detail": "the job database (Redis) is unreachable; try again shortly"
            }
            assert response.headers["retry-after"] == "5"
            files = {"file": (small.name, small.read_bytes())}
            response = client.post("/v1/jobs", files=files)
            assert response.status_code == 503
            assert "Redis" in response.json()["detail"]
            assert sorted(p.name for p in (settings.data_dir / "jobs").iterdir()) == sorted(
                queued
            )  # the refused upload left nothing behind
            response = client.get("/readyz")
            assert response.status_code == 503
            assert response.json()["detail"].startswith("Redis is unreachable")

            # Same port, same directory: the clients reconnect by themselves.
            server = RedisServer(
                persistence_dir=persistence,
                binary=find_redis_server(prefer_path=True),
                port=server.port,
            )
            server.start()
            jobs = [client.get(f"/v1/jobs/{job}") for job in queued]
            assert [r.status_code for r in jobs] == [200, 200]
            assert [r.json()["status"] for r in jobs] == ["queued", "queued"]
            assert Redis.from_url(server.url).llen(f"rq:queue:{settings.queue_name}") == 2

            with running_worker(settings, tmp_path / "worker.log") as worker:
                for job in queued:
                    wait_for(
                        lambda job=job: (
                            client.get(f"/v1/jobs/{job}").json()["status"] == "finished"
                        ),
                        timeout=60,
                        message="a job queued before the restart to finish",
                    )
                # A worker waiting for jobs lives through a restart too.
                server.stop()
                time.sleep(1.0)
                server = RedisServer(
                    persistence_dir=persistence,
                    binary=find_redis_server(prefer_path=True),
                    port=server.port,
                )
                server.start()
                later = wait_for(
                    lambda: (
                        (r := client.post("/v1/jobs", files=files)).status_code == 202
                        and r.json()["id"]
                    ),
                    timeout=30,
                    message="the API to take jobs again",
                )
                wait_for(
                    lambda: client.get(f"/v1/jobs/{later}").json()["status"] == "finished",
                    timeout=60,
                    message="a job submitted after the restart to finish",
                )
                assert worker.process.poll() is None
            result = client.get(f"/v1/jobs/{queued[0]}/result", params={"format": "npz"})
            assert result.status_code == 200
            (tmp_path / "r.npz").write_bytes(result.content)
            assert read_result(tmp_path / "r.npz").shapes.shape == (10, 300, 3)
            assert client.get("/v1/jobs").json()["total"] == 3
    finally:
        server.stop()
