"""Schemathesis against ``openapi/openapi.json``: generated requests never get a 5xx.

Schemathesis' own runner (``st run``; schemathesis is in the ``test`` extra) generates requests
from the committed OpenAPI document: the documented examples, the coverage phase (boundary
values, each constraint broken in turn, huge numbers, odd strings) and random fuzzing. They
go over loopback to the app served by uvicorn on the throwaway Redis. Two runs: every
operation with generated job ids (which name no job), and the job routes on a finished job,
so that the code behind a found job is reached too. Bounded: 50 and 20 examples per
operation and phase, about 5-10 s per run, a hard timeout of 90 s.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import uuid
from pathlib import Path

import httpx
import pytest
from redis import Redis

from service.job_store import JobStore
from service.openapi import DEFAULT_PATH
from service.settings import Settings
from service.storage import LocalStorage
from worker.jobs import execute

TRACKS = [[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]],
          [[0.0, 0.1], [1.0, 0.1], [0.1, 0.9], [1.0, 1.0]],
          [[0.1, 0.0], [1.0, 0.0], [0.0, 1.0], [0.9, 1.1]]]  # fmt: skip

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("schemathesis") is None,
    reason="schemathesis is not installed (pip install -e '.[test]')",
)


def _run_schemathesis(base_url: str, config: Path, *selection: str, examples: int = 20) -> None:
    command = [
        sys.executable, "-m", "schemathesis.cli",
        "--config-file", str(config), "--no-color", "run", str(DEFAULT_PATH),
        "--url", base_url,
        "--checks", "not_a_server_error",
        "--phases", "examples,coverage,fuzzing",
        "--max-examples", str(examples),
        "--request-timeout", "15",
        "--workers", "1",
        *selection,
    ]  # fmt: skip
    # In the config's directory: schemathesis keeps a cache (.schemathesis/) where it runs.
    run = subprocess.run(command, capture_output=True, text=True, timeout=90, cwd=config.parent)
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    assert "generated" in run.stdout  # it did test something


def test_generated_requests_get_no_server_error(live_api: str, tmp_path: Path) -> None:
    config = tmp_path / "schemathesis.toml"
    config.write_text("")
    # /readyz answers 503 by design here: no worker runs in this test.
    _run_schemathesis(live_api, config, "--exclude-path", "/readyz", examples=50)


def test_requests_about_an_existing_job_get_no_server_error(
    live_api: str, settings: Settings, tmp_path: Path
) -> None:
    with httpx.Client(base_url=live_api, timeout=30) as http:
        response = http.post("/v1/jobs", json={"tracks": TRACKS, "params": {"max_iter": 5}})
        assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    connection = Redis.from_url(settings.require_redis_url())
    store = JobStore(connection, retention_seconds=settings.result_ttl)
    outcome = execute(uuid.UUID(job_id), store, LocalStorage(settings.data_dir), settings)
    assert outcome["status"] == "finished", outcome
    connection.close()

    config = tmp_path / "schemathesis.toml"
    config.write_text(f"[parameters]\n{json.dumps('path.job_id')} = {json.dumps(job_id)}\n")
    # DELETE would end the job the other operations are about: left to the first test.
    _run_schemathesis(
        live_api, config, "--include-path-regex", "^/v1/jobs/", "--exclude-method", "DELETE"
    )
    with httpx.Client(base_url=live_api, timeout=30) as http:
        assert http.get(f"/v1/jobs/{job_id}").json()["status"] == "finished"
