"""Fixtures of the service tests: settings, the app, inputs, a live API and a worker process.

Everything runs against the throwaway Redis of ``tests/redis_server.py`` (flushed per test)
and a temporary data directory. Helpers live in ``service_testing.py``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from api_thread import serving
from fastapi.testclient import TestClient
from redis import Redis
from service_testing import WorkerProcess, measurements_of, running_worker

from moju_core.datasets import Sequence, make_sequence
from moju_core.io import write_measurements
from service.app import create_app
from service.settings import Settings


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    """End the run with a line saying that the browser tests did not run, and how to run them."""
    import os

    chromium = Path(os.environ.get("MOJU_TEST_CHROMIUM", "/usr/bin/chromium"))
    skipped = terminalreporter.stats.get("skipped", [])
    if chromium.is_file() or not any("test_service_browser" in r.nodeid for r in skipped):
        return
    terminalreporter.write_line(
        f"the browser tests of the web page did not run: no chromium at {chromium} "
        "(sudo apt-get install chromium, or set MOJU_TEST_CHROMIUM to a chromium binary)",
        yellow=True,
        bold=True,
    )


@pytest.fixture(scope="session")
def small_sequence() -> Sequence:
    """face1 with 300 points and 10 frames (solves in well under a second)."""
    return make_sequence("face1", n_points=300)


@pytest.fixture(scope="session")
def long_sequence() -> Sequence:
    """face1 with 2000 points: with LONG_PARAMS a job that runs until cancelled."""
    return make_sequence("face1", n_points=2000)


@pytest.fixture
def input_file(tmp_path: Path, small_sequence: Sequence) -> Path:
    """An npz upload with W, R, gt, faces and colours."""
    return write_measurements(tmp_path / "face_small.npz", measurements_of(small_sequence))


@pytest.fixture
def settings(redis_url: str, tmp_path: Path) -> Settings:
    """Settings of one test: its own data directory, the flushed test Redis."""
    return Settings(redis_url=redis_url, data_dir=tmp_path / "data", cleanup_interval=0)


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    """The app in-process (lifespan run), against the test Redis."""
    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture
def redis_client(redis_url: str) -> Iterator[Redis]:
    """A client of the test Redis (bytes replies, like the service's)."""
    connection = Redis.from_url(redis_url)
    yield connection
    connection.close()


@pytest.fixture
def worker(settings: Settings, tmp_path: Path) -> Iterator[WorkerProcess]:
    """One worker process for the test."""
    with running_worker(settings, tmp_path / "worker.log") as process:
        yield process


@pytest.fixture
def live_api(settings: Settings) -> Iterator[str]:
    """The API served by uvicorn over real sockets (in a thread); yields its base URL."""
    with serving(settings) as url:
        yield url
