"""Access control: API keys, jobs private to their key, keys kept out of logs, queue limits,
CORS."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr
from service_testing import REPO_ROOT, wait_for

from service.app import create_app
from service.auth import key_digest, owner_id
from service.job_store import JobStore, active_key
from service.processes import free_port, stop_process
from service.settings import Settings

ALICE = "alice-0123456789abcdef-key"
BOB = "bob-fedcba9876543210-key"
WRONG = "mallory-not-a-key-0000000"
TRACKS = [[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]],
          [[0.0, 0.1], [1.0, 0.1], [0.1, 0.9], [1.0, 1.0]],
          [[0.1, 0.0], [1.0, 0.0], [0.0, 1.0], [0.9, 1.1]]]  # fmt: skip


def _as(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


@pytest.fixture
def keyed_settings(settings: Settings) -> Settings:
    """Alice's key in clear, Bob's as a digest only."""
    keys = f"{ALICE}, sha256:{key_digest(BOB)}"
    return settings.model_copy(update={"api_keys": SecretStr(keys)})


@pytest.fixture
def keyed(keyed_settings: Settings):
    with TestClient(create_app(keyed_settings)) as client:
        yield client


def _submit(client: TestClient, key: str | None) -> httpx.Response:
    headers = _as(key) if key else {}
    return client.post("/v1/jobs", json={"tracks": TRACKS}, headers=headers)


def _v1_requests() -> list[tuple[str, str]]:
    job = uuid.uuid4()
    return [
        ("POST", "/v1/jobs"),
        ("GET", "/v1/jobs"),
        ("GET", f"/v1/jobs/{job}"),
        ("DELETE", f"/v1/jobs/{job}"),
        ("GET", f"/v1/jobs/{job}/events"),
        ("GET", f"/v1/jobs/{job}/result?format=npz"),
        ("GET", f"/v1/jobs/{job}/frames/0.ply"),
        ("GET", f"/v1/jobs/{job}/frames.zip"),
        ("GET", f"/v1/jobs/{job}/metrics"),
        ("GET", f"/v1/jobs/{job}/viewer-data"),
        ("GET", f"/v1/jobs/{job}/viewer-data/frames/0"),
        ("GET", f"/v1/jobs/{job}/tracks.npz"),
        ("GET", f"/v1/jobs/{job}/first-frame.png"),
        ("GET", "/v1/jobs/not-a-uuid"),
        ("GET", "/v1/jobs?limit=100000"),  # an invalid query still needs a key first
    ]


def test_every_v1_route_needs_a_key(keyed: TestClient) -> None:
    operations = {
        (method.upper(), path)
        for path, methods in keyed.app.openapi()["paths"].items()
        if path.startswith("/v1")
        for method in methods
    }
    probed = {
        (method, path.split("?")[0].replace(path.split("/")[3], "{job_id}", 1))
        if path.count("/") > 2
        else (method, path.split("?")[0])
        for method, path in _v1_requests()
    }
    probed = {
        (m, p.replace("/0.ply", "/{frame}.ply").replace("frames/0", "frames/{frame}"))
        for m, p in probed
    }
    assert operations <= probed, operations - probed  # every /v1 operation is probed
    for method, path in _v1_requests():
        for headers in ({}, _as(WRONG), {"X-API-Key": WRONG}, {"Authorization": ALICE}):
            response = keyed.request(method, path, headers=headers, json={"tracks": TRACKS})
            assert response.status_code == 401, (method, path, headers, response.text)
            assert response.headers["www-authenticate"] == "Bearer"
            detail = response.json()["detail"]
            assert "API key" in detail and WRONG not in detail and ALICE not in detail
    no_key = keyed.get("/v1/jobs").json()["detail"]
    assert no_key == (
        "this server needs an API key: send it as 'Authorization: Bearer <key>' or as "
        "'X-API-Key: <key>'"
    )
    assert "not valid" in keyed.get("/v1/jobs", headers=_as(WRONG)).json()["detail"]
    # Probes, the page and the API description stay open.
    assert keyed.get("/healthz").status_code == 200
    assert keyed.get("/readyz").status_code == 503  # no worker, but not a 401
    assert keyed.get("/").status_code == 200
    assert keyed.get("/openapi.json").status_code == 200
    # Both headers work, for the key in clear and the one configured as a digest.
    assert keyed.get("/v1/jobs", headers=_as(ALICE)).status_code == 200
    assert keyed.get("/v1/jobs", headers={"X-API-Key": BOB}).status_code == 200


def test_jobs_are_invisible_to_other_keys(keyed: TestClient, keyed_settings: Settings) -> None:
    alices = _submit(keyed, ALICE).json()["id"]
    bobs = _submit(keyed, BOB).json()["id"]
    missing = {
        "detail": f"job {alices} not found: it never existed, was deleted, or its retention "
        "period ended"
    }
    for suffix in ("", "/events", "/result", "/frames/0.ply", "/frames.zip", "/metrics",
                   "/viewer-data", "/viewer-data/frames/0"):  # fmt: skip
        response = keyed.get(f"/v1/jobs/{alices}{suffix}", headers=_as(BOB))
        assert response.status_code == 404, suffix
        assert response.json() == missing, suffix
    assert keyed.delete(f"/v1/jobs/{alices}", headers=_as(BOB)).status_code == 404
    assert keyed.get(f"/v1/jobs/{alices}", headers=_as(ALICE)).json()["status"] == "queued"
    assert (keyed_settings.data_dir / "jobs" / alices).is_dir()  # Bob's DELETE did nothing

    listed = {key: keyed.get("/v1/jobs", headers=_as(key)).json() for key in (ALICE, BOB)}
    assert [job["id"] for job in listed[ALICE]["items"]] == [alices]
    assert [job["id"] for job in listed[BOB]["items"]] == [bobs]
    assert listed[ALICE]["total"] == listed[BOB]["total"] == 1
    # The job resource does not show whose it is.
    assert "owner" not in keyed.get(f"/v1/jobs/{bobs}", headers=_as(BOB)).json()

    assert keyed.delete(f"/v1/jobs/{alices}", headers=_as(ALICE)).status_code == 204
    assert keyed.get(f"/v1/jobs/{alices}", headers=_as(ALICE)).json()["status"] == "cancelled"


def test_keys_from_a_file_in_clear_or_hashed(settings: Settings, tmp_path: Path) -> None:
    key_file = tmp_path / "keys"
    key_file.write_text(f"# operators' keys\n{ALICE}\n\nsha256:{key_digest(BOB).upper()}  # bob\n")
    with_file = settings.model_copy(update={"api_keys_file": key_file})
    with TestClient(create_app(with_file)) as client:
        for key in (ALICE, BOB):
            assert client.get("/v1/jobs", headers=_as(key)).status_code == 200
        assert client.get("/v1/jobs", headers=_as(WRONG)).status_code == 401

    for bad, message in (
        ("short-key\n", "at least 16 characters"),
        ("sha256:abc\n", "not followed by 64 hex digits"),
        ("# nothing but a comment\n", "hold no key"),
    ):
        key_file.write_text(bad)
        with pytest.raises(ValueError, match=message) as refused:
            create_app(with_file)
        assert "short-key" not in str(refused.value)
    with pytest.raises(ValueError, match="cannot read MOJU_API_KEYS_FILE"):
        create_app(settings.model_copy(update={"api_keys_file": tmp_path / "absent"}))


def test_keys_never_appear_in_logs(keyed_settings: Settings, tmp_path: Path) -> None:
    """A real uvicorn process, debug logging and access log on: the keys are never written."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOJU_")}
    env.update(
        MOJU_REDIS_URL=keyed_settings.require_redis_url(),
        MOJU_DATA_DIR=str(keyed_settings.data_dir),
        MOJU_API_KEYS=keyed_settings.api_keys.get_secret_value(),
        MOJU_CLEANUP_INTERVAL="0",
        PYTHONPATH=str(REPO_ROOT),
    )
    log_path = tmp_path / "api.log"
    command = [sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app",
               "--host", "127.0.0.1", "--port", str(port), "--log-level", "trace"]  # fmt: skip
    with open(log_path, "wb") as log:
        server = subprocess.Popen(command, env=env, cwd=tmp_path, stdout=log, stderr=log)
    base = f"http://127.0.0.1:{port}"
    try:
        with httpx.Client(base_url=base, timeout=10) as http:
            wait_for(lambda: _answers(http), timeout=30, message="the API to start")
            job = http.post("/v1/jobs", json={"tracks": TRACKS}, headers=_as(ALICE)).json()
            http.get(f"/v1/jobs/{job['id']}", headers={"X-API-Key": ALICE})
            http.get("/v1/jobs", headers=_as(BOB))
            http.get(f"/v1/jobs/{job['id']}", headers=_as(BOB))  # 404
            http.get("/v1/jobs", headers=_as(WRONG))  # 401
            http.get("/v1/jobs", headers={"X-API-Key": WRONG})
            http.get("/v1/jobs", params={"api_key": ALICE, "token": BOB})  # 401, and logged
            http.post("/v1/jobs", json={"tracks": [[1]]}, headers=_as(ALICE))  # 422
            http.delete(f"/v1/jobs/{job['id']}", headers=_as(ALICE))
    finally:
        stop_process(server, timeout=10)
    text = log_path.read_text(errors="replace")
    assert "GET /v1/jobs" in text  # the access log was on
    assert f"queued for {owner_id(key_digest(ALICE))}" in text  # owner ids are logged
    assert "no valid API key" in text
    for secret in (ALICE, BOB, WRONG, key_digest(ALICE), key_digest(BOB)):
        assert secret not in text


def _answers(http: httpx.Client) -> bool:
    try:
        return http.get("/healthz").status_code == 200
    except httpx.TransportError:
        time.sleep(0.1)
        return False


def test_queued_jobs_per_key_are_limited(keyed_settings: Settings) -> None:
    limited = keyed_settings.model_copy(update={"max_queued_jobs_per_key": 2})
    with TestClient(create_app(limited)) as client:
        first, second = (_submit(client, ALICE).json()["id"] for _ in range(2))
        refused = _submit(client, ALICE)
        assert refused.status_code == 429
        assert refused.headers["retry-after"] == "10"
        assert refused.json()["detail"] == (
            "this API key has 2 jobs queued or running, the most allowed "
            "(MOJU_MAX_QUEUED_JOBS_PER_KEY); wait until some end (or cancel some) and submit "
            "again in 10 s"
        )
        assert len(list((limited.data_dir / "jobs").iterdir())) == 2  # nothing stored
        assert client.get("/v1/jobs", headers=_as(ALICE)).json()["total"] == 2
        assert _submit(client, BOB).status_code == 202  # each key has its own slots
        # An ended job frees its slot.
        assert client.delete(f"/v1/jobs/{first}", headers=_as(ALICE)).status_code == 204
        assert _submit(client, ALICE).status_code == 202
        assert _submit(client, ALICE).status_code == 429
        del second


def test_limit_without_keys_and_reclaimed_slots(settings: Settings, redis_client) -> None:
    limited = settings.model_copy(update={"max_queued_jobs_per_key": 1})
    with TestClient(create_app(limited)) as client:
        assert _submit(client, None).status_code == 202
        assert _submit(client, None).status_code == 429
    # A slot taken by a submission whose API process died before it stored the job is
    # given back once it is old enough.
    store = JobStore(redis_client, retention_seconds=60)
    redis_client.delete(active_key(""))
    redis_client.zadd(active_key(""), {str(uuid.uuid4()): time.time() - 3600})
    assert store.reserve("", uuid.uuid4(), 1)
    assert not store.reserve("", uuid.uuid4(), 1)
    assert store.reserve("", uuid.uuid4(), 0)  # 0: no limit


def test_cors_is_off_by_default_and_configurable(settings: Settings) -> None:
    origin = "https://viewer.example.org"
    preflight = {"Origin": origin, "Access-Control-Request-Method": "POST",
                 "Access-Control-Request-Headers": "authorization"}  # fmt: skip
    with TestClient(create_app(settings)) as client:
        response = client.options("/v1/jobs", headers=preflight)
        assert "access-control-allow-origin" not in response.headers
        response = client.get("/v1/jobs", headers={"Origin": origin})
        assert "access-control-allow-origin" not in response.headers

    allowed = settings.model_copy(update={"cors_origins": f"{origin}, https://other.example"})
    with TestClient(create_app(allowed)) as client:
        response = client.options("/v1/jobs", headers=preflight)
        assert response.status_code == 200
        assert response.headers["access-control-allow-origin"] == origin
        assert "authorization" in response.headers["access-control-allow-headers"].lower()
        response = client.get("/v1/jobs", headers={"Origin": origin})
        assert response.headers["access-control-allow-origin"] == origin
        assert "Location" in response.headers["access-control-expose-headers"]
        elsewhere = {**preflight, "Origin": "https://evil.example"}
        response = client.options("/v1/jobs", headers=elsewhere)
        assert "access-control-allow-origin" not in response.headers
