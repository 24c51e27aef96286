"""Helpers of the service tests: inputs, long-job parameters, worker processes, polling."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from redis import Redis
from rq import Queue, Worker

from moju_core.datasets import Sequence
from moju_core.io import Measurements
from service.processes import signal_until_exit
from service.settings import Settings

REPO_ROOT = Path(__file__).resolve().parents[2]

#: Parameters that keep a 2000-point job busy for tens of seconds: the penalty grows so slowly
#: that neither the gap nor rho_max stops the loop before max_iter.
LONG_PARAMS = {"max_iter": 10_000, "tol": 0.0, "rho_growth": 1.0005, "rho_max": 1e12}


def measurements_of(sequence: Sequence, *, extras: bool = True) -> Measurements:
    """The sequence as an upload: W, and with ``extras`` also R, gt, faces and colours."""
    if not extras:
        return Measurements(W=sequence.W)
    return Measurements(
        W=sequence.W,
        rotations=sequence.rotations,
        ground_truth=sequence.shapes,
        faces=sequence.faces,
        colors=sequence.colors,
    )


@dataclass
class WorkerProcess:
    """A ``python -m worker`` child process and its log file."""

    process: subprocess.Popen
    log_path: Path

    def log(self) -> str:
        """Everything the worker wrote so far."""
        return self.log_path.read_text(errors="replace")


def worker_environment(settings: Settings, **extra: str) -> dict[str, str]:
    """The environment a worker needs to serve ``settings``: queue, data directory, Redis, and
    the settings that workers read (heartbeats, memory limit, threads)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOJU_")}
    env.update(
        MOJU_REDIS_URL=settings.require_redis_url(),
        MOJU_DATA_DIR=str(settings.data_dir),
        MOJU_QUEUE_NAME=settings.queue_name,
        MOJU_HEARTBEAT_INTERVAL=repr(settings.heartbeat_interval),
        MOJU_HEARTBEAT_TTL=repr(settings.heartbeat_ttl),
        MOJU_WORKER_MEMORY_BYTES=str(settings.worker_memory_bytes),
        MOJU_RESULT_TTL=str(settings.result_ttl),
        PYTHONPATH=os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")])),
    )
    env.update(extra)
    return env


@contextlib.contextmanager
def running_worker(settings: Settings, log_path: Path, **env: str) -> Iterator[WorkerProcess]:
    """A real RQ worker process (forking work horses), registered before this yields."""
    with open(log_path, "wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "worker"],
            env=worker_environment(settings, **env),
            cwd=REPO_ROOT,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    worker = WorkerProcess(process, log_path)
    connection = Redis.from_url(settings.require_redis_url())
    queue = Queue(settings.queue_name, connection=connection)
    try:
        deadline = time.monotonic() + 60
        while Worker.count(connection=connection, queue=queue) == 0:
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the worker did not start:\n{worker.log()}")
            time.sleep(0.05)
        yield worker
    finally:
        connection.close()
        # Warm shutdown, then cold (repeated until the worker exits).
        signal_until_exit([process], timeout=15)


def wait_for(
    predicate: Callable[[], Any], timeout: float, interval: float = 0.05, message: str = "it"
) -> Any:
    """Poll ``predicate`` until it returns something truthy (returned); fail after ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout} s waiting for {message}")


def collapsed_tracks(n_frames: int = 5, n_points: int = 20) -> np.ndarray:
    """Every point at the same image position in every frame: a valid upload (finite, right
    shape) that the solver refuses with a MeasurementError of its own."""
    return np.full((n_frames, n_points, 2), 3.0)
