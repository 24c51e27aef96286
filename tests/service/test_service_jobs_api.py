"""Job resource routes without a worker: read, list, delete, unfinished downloads, probes."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from redis import Redis
from rq.job import Job as RQJob

from service.app import create_app
from service.job_store import record_key
from service.processes import free_port
from service.settings import Settings


def submit(client: TestClient, path: Path, **params) -> dict:
    files = {"file": (path.name, path.read_bytes())}
    response = client.post("/v1/jobs", files=files, data={"params": json.dumps(params)})
    assert response.status_code == 202, response.text
    return response.json()


def test_unknown_and_malformed_job_ids_are_404(client: TestClient) -> None:
    missing = uuid.uuid4()
    response = client.get(f"/v1/jobs/{missing}")
    assert response.status_code == 404
    assert response.json() == {
        "detail": f"job {missing} not found: it never existed, was deleted, or its retention "
        "period ended"
    }
    for bad in ("abc", "%2E%2E", str(missing).upper(), str(uuid.uuid1())):
        response = client.get(f"/v1/jobs/{bad}")
        assert response.status_code == 404, bad
        assert "job ids are UUID4 strings" in response.json()["detail"]
    # A path that climbs out of /v1/jobs matches no route at all.
    response = client.get("/v1/jobs/..%2F..%2Fetc%2Fpasswd")
    assert response.status_code == 404
    assert response.json()["detail"].startswith("no endpoint GET")
    for route in ("/result", "/frames.zip", "/frames/0.ply", "/metrics", "/events"):
        assert client.get(f"/v1/jobs/{missing}{route}").status_code == 404, route
    assert client.delete(f"/v1/jobs/{missing}").status_code == 404


def test_list_is_newest_first_with_offset_pagination(client: TestClient, input_file: Path) -> None:
    ids = [submit(client, input_file, seed=seed)["id"] for seed in range(3)]

    first = client.get("/v1/jobs", params={"limit": 2}).json()
    assert first["pagination"] == "offset"
    assert [job["id"] for job in first["items"]] == ids[::-1][:2]
    assert (first["total"], first["limit"], first["offset"], first["next_offset"]) == (3, 2, 0, 2)

    second = client.get("/v1/jobs", params={"limit": 2, "offset": first["next_offset"]}).json()
    assert [job["id"] for job in second["items"]] == [ids[0]]
    assert second["next_offset"] is None

    response = client.get("/v1/jobs", params={"limit": 1000})
    assert response.status_code == 422
    assert "query parameter 'limit'" in response.json()["detail"]


def test_list_skips_records_that_expired(
    client: TestClient, input_file: Path, redis_client: Redis
) -> None:
    kept, expired = (submit(client, input_file)["id"] for _ in range(2))
    redis_client.delete(record_key(uuid.UUID(expired)))
    page = client.get("/v1/jobs").json()
    assert [job["id"] for job in page["items"]] == [kept]
    assert page["total"] == 1


def test_downloads_of_unfinished_jobs_are_409(client: TestClient, input_file: Path) -> None:
    job = submit(client, input_file)
    for route in ("/result?format=npz", "/result", "/frames/0.ply", "/frames.zip", "/metrics"):
        response = client.get(f"/v1/jobs/{job['id']}{route}")
        assert response.status_code == 409, route
        assert response.json()["detail"] == (
            f"job {job['id']} is queued; its result is not ready yet: wait until its status "
            f"is 'finished' (GET /v1/jobs/{job['id']} or /v1/jobs/{job['id']}/events)"
        )
    response = client.get(f"/v1/jobs/{job['id']}/result", params={"format": "zip"})
    assert response.status_code == 422
    assert "query parameter 'format'" in response.json()["detail"]


def test_metrics_need_ground_truth(client: TestClient, tmp_path: Path, small_sequence) -> None:
    import numpy as np

    np.savez(tmp_path / "w.npz", W=small_sequence.W)
    job = submit(client, tmp_path / "w.npz")
    assert job["links"]["metrics"] is None
    response = client.get(f"/v1/jobs/{job['id']}/metrics")
    assert response.status_code == 404
    assert "submitted without ground truth" in response.json()["detail"]


def test_delete_queued_job_cancels_it_and_removes_its_files(
    client: TestClient, input_file: Path, settings: Settings, redis_client: Redis
) -> None:
    job = submit(client, input_file)
    job_dir = settings.data_dir / "jobs" / job["id"]
    assert job_dir.is_dir()

    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204

    cancelled = client.get(f"/v1/jobs/{job['id']}").json()
    assert cancelled["status"] == "cancelled" and cancelled["ended_at"] is not None
    assert not job_dir.exists()
    # RQ's own cancel took it out of the queue.
    assert RQJob.fetch(job["id"], connection=redis_client).get_status() == "canceled"
    assert redis_client.llen(f"rq:queue:{settings.queue_name}") == 0
    # The tombstone expires with the retention period.
    assert 0 < redis_client.ttl(record_key(uuid.UUID(job["id"]))) <= settings.result_ttl
    response = client.get(f"/v1/jobs/{job['id']}/result")
    assert response.status_code == 409 and "was cancelled" in response.json()["detail"]

    # Deleting an ended job removes it for good.
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    assert client.get(f"/v1/jobs/{job['id']}").status_code == 404
    assert client.get("/v1/jobs").json()["total"] == 0


def test_health_and_readiness_without_worker(client: TestClient) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    response = client.get("/readyz")
    assert response.status_code == 503
    assert "no worker is registered on queue 'moju'" in response.json()["detail"]


def test_redis_down_answers_503(tmp_path: Path) -> None:
    dead = Settings(
        redis_url=f"redis://127.0.0.1:{free_port()}/0", data_dir=tmp_path, cleanup_interval=0
    )
    with TestClient(create_app(dead)) as client:
        assert client.get("/healthz").status_code == 200
        response = client.get(f"/v1/jobs/{uuid.uuid4()}")
        assert response.status_code == 503
        assert "Redis" in response.json()["detail"]
        response = client.get("/readyz")
        assert response.status_code == 503
        assert "Redis is unreachable" in response.json()["detail"]


def test_app_without_redis_url_says_how_to_configure(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="MOJU_REDIS_URL is not set"):
        with TestClient(create_app(Settings(redis_url=None, data_dir=tmp_path))):
            pass


def test_job_lost_from_the_queue_is_reported_failed(
    client: TestClient, input_file: Path, redis_client: Redis
) -> None:
    job = submit(client, input_file)
    RQJob.fetch(job["id"], connection=redis_client).delete()  # e.g. `rq empty` by an operator
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert failed["status"] == "failed"
    assert failed["error"].startswith("the job queue lost this job")
    assert client.get("/v1/jobs").json()["items"][0]["status"] == "failed"
