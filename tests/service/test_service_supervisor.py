"""The supervisor of ``moju serve``: restart policy, crash loop, and what ``/readyz`` says.

These run the supervisor in the test process with its real children (an embedded
``redis-server``, ``python -m worker`` and uvicorn). Everything waits for events (a death
noticed, a restart logged, a probe's answer), never for a fixed time. The end-to-end kills of
a running ``moju serve`` are in ``tests/cli/test_service_commands.py``.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from service.processes import free_port
from service.supervisor import Child, RestartPolicy, ServeOptions, Supervisor

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="the supervisor finds work horses in /proc"
)


def _options(tmp_path: Path, policy: RestartPolicy) -> ServeOptions:
    env = {"MOJU_HEARTBEAT_INTERVAL": "0.5", "MOJU_HEARTBEAT_TTL": "2"}
    return ServeOptions(
        port=free_port(), workers=1, data_dir=tmp_path / "data", grace=1.0, extra_env=env,
        restart=policy, log_level="warning",
    )  # fmt: skip


class CrashingWorkers(Supervisor):
    """A supervisor whose workers exit at once with status 3 (a broken installation)."""

    def worker_command(self) -> list[str]:
        return [sys.executable, "-c", "import sys; sys.exit(3)"]


def test_restart_policy_backs_off_and_gives_up() -> None:
    policy = RestartPolicy(first_delay=0.5, max_delay=4.0, stable_after=30, max_restarts=5)
    child = Child("worker 1", "worker")
    delays = []
    for death in range(5):
        child.started_at = 100.0 + death
        delays.append(policy.delay(child, now=100.5 + death))
    assert delays == [0.5, 1.0, 2.0, 4.0, 4.0]
    assert policy.delay(child, now=106.0) is None  # a sixth death within the window
    # A child that lived long starts over at the first delay, and old deaths are forgotten.
    child = Child("worker 1", "worker", started_at=0.0, quick_deaths=4, deaths=[0.0, 1.0])
    assert policy.delay(child, now=500.0) == 0.5
    assert child.deaths == [500.0]


def test_crash_loop_gives_up_with_a_clear_message(tmp_path: Path, caplog) -> None:
    caplog.set_level(logging.INFO, logger="service.supervisor")
    policy = RestartPolicy(first_delay=0.05, max_delay=0.2, max_restarts=3, window=600)
    supervisor = CrashingWorkers(_options(tmp_path, policy))
    try:
        supervisor.start()
        assert supervisor.watch() == 1
    finally:
        supervisor.stop()
    restarts = [r for r in caplog.records if "worker 1 started again" in r.getMessage()]
    deaths = [r for r in caplog.records if "status 3; restarting it in" in r.getMessage()]
    assert len(restarts) == 3 and len(deaths) == 3
    assert supervisor.gave_up is not None
    assert "worker 1 died 4 times within 600 s (last exited with exit status 3)" in (
        supervisor.gave_up
    )
    assert supervisor.redis is not None and supervisor.redis.process is None  # all stopped


def _readyz(base_url: str) -> httpx.Response:
    return httpx.get(f"{base_url}/readyz", timeout=10)


def _until(condition, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


def test_readyz_names_the_dead_worker_until_it_is_back(tmp_path: Path) -> None:
    # A pause far longer than the test, so that the worker stays down until we restart it.
    policy = RestartPolicy(first_delay=3600, max_delay=3600)
    supervisor = Supervisor(_options(tmp_path, policy))
    try:
        base_url = supervisor.start()
        _until(lambda: _readyz(base_url).status_code == 200, "a registered worker")
        worker = supervisor.worker_children[0]
        old_pid = worker.pid
        assert old_pid is not None
        os.kill(old_pid, signal.SIGKILL)
        _until(lambda: supervisor.check_children() and worker.restart_at is not None, "a death")
        answer = _readyz(base_url)
        assert answer.status_code == 503
        assert "worker 1 exited with signal SIGKILL; restarting in" in answer.json()["detail"]

        worker.restart_at = time.monotonic()  # due now
        assert supervisor.check_children()
        assert worker.pid not in (None, old_pid) and worker.restart_at is None
        _until(lambda: _readyz(base_url).status_code == 200, "readiness after the restart")
    finally:
        supervisor.stop()


#: A stand-in for an RQ worker busy with a job: it handles the warm-shutdown signal late (as a
#: niced worker next to solves may), then, like RQ, ignores a signal within a second of the
#: moment it handled that one; a later one is its cold shutdown, which it reports.
LATE_WORKER = """
import pathlib, signal, sys, time
report, warm = pathlib.Path(sys.argv[1]), []
def handle(signum, frame):
    if not warm:
        time.sleep(0.5)
        warm.append(time.monotonic())
    elif time.monotonic() - warm[0] >= 1.0:
        report.write_text("cold shutdown")
        sys.exit(0)
signal.signal(signal.SIGTERM, handle)
report.write_text("ready")
while True:
    time.sleep(0.05)
"""


def test_workers_that_handle_the_warm_signal_late_still_shut_down_cold(tmp_path: Path) -> None:
    """A single cold-shutdown signal one second after the warm one is ignored by a worker
    that handled the warm one late: it was killed and its job never recorded as interrupted."""
    options = _options(tmp_path, RestartPolicy())
    options.grace = 0.0
    supervisor = Supervisor(options)
    reports = [tmp_path / f"worker{i}.txt" for i in range(2)]
    for i, report in enumerate(reports):
        child = Child(f"worker {i + 1}", "worker")
        child.process = subprocess.Popen([sys.executable, "-c", LATE_WORKER, str(report)])
        supervisor.worker_children.append(child)
    _until(lambda: all(r.exists() for r in reports), "the stand-in workers")
    supervisor._stop_workers()
    assert [r.read_text() for r in reports] == ["cold shutdown"] * 2
    assert [c.process.returncode for c in supervisor.worker_children] == [0, 0]
