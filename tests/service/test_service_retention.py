"""Retention: the API's periodic sweep deletes the files of jobs whose records expired."""

from __future__ import annotations

import os
import time
from pathlib import Path

from fastapi.testclient import TestClient
from redis import Redis
from service_testing import wait_for

from service.app import create_app
from service.settings import Settings


def _submit(client: TestClient, path: Path) -> str:
    files = {"file": (path.name, path.read_bytes())}
    response = client.post("/v1/jobs", files=files, data={"params": '{"max_iter": 5}'})
    assert response.status_code == 202, response.text
    return response.json()["id"]


def test_expired_jobs_lose_their_files_to_the_periodic_sweep(
    settings: Settings, input_file: Path, redis_client: Redis
) -> None:
    sweeping = settings.model_copy(update={"cleanup_interval": 1, "result_ttl": 1})
    jobs = sweeping.data_dir / "jobs"
    with TestClient(create_app(sweeping)) as client:
        expired, ended, young, live = (_submit(client, input_file) for _ in range(4))
        # An ended job's record expires after MOJU_RESULT_TTL (1 s here); Redis drops it.
        assert client.delete(f"/v1/jobs/{ended}").status_code == 204  # cancelled: TTL set
        wait_for(lambda: not redis_client.exists(f"moju:job:{ended}"), timeout=10)
        # A record that vanished (expired) while its directory is old: swept.
        redis_client.delete(f"moju:job:{expired}")
        old = time.time() - 3600
        os.utime(jobs / live, (old, old))
        os.utime(jobs / expired, (old, old))
        wait_for(lambda: not (jobs / expired).exists(), timeout=10, message="the sweep")
        # A directory younger than the grace period is kept even without a record (the API
        # writes a job's input before its record), and live jobs are never touched.
        redis_client.delete(f"moju:job:{young}")
        time.sleep(2.5)  # two more sweeps
        assert (jobs / young).is_dir()
        assert (jobs / live).is_dir()  # old, but its record is there
        listed = client.get("/v1/jobs").json()
        assert [job["id"] for job in listed["items"]] == [live]  # index entries pruned
    assert not (jobs / ended).exists()  # deleted by the DELETE itself
