"""Could RQ's own ``Retry`` and ``StartedJobRegistry.cleanup()`` recover jobs of lost workers?

The service notices a lost worker through a lease its work horse renews
(:mod:`worker.heartbeat`) and retries or fails the job from the API's watchdog
(:mod:`service.watchdog`). RQ has its own mechanism: a job enqueued with ``Retry(max=n)``
stays in the queue's started-job registry while its worker sends heartbeats, and
``StartedJobRegistry.cleanup()`` re-enqueues (or fails) the jobs whose entry expired. This
script measures what that mechanism gives, against a throwaway Redis and real ``rq`` worker
processes (a signal is sent to the worker and to its work horse, which RQ puts in a process
group of its own):

* ``kill``: a worker and its work horse are SIGKILLed two seconds into a job; an outside
  loop calls ``cleanup()`` every second (as the API's watchdog could). Reported: the seconds
  from the kill to the job being queued again.
* ``pause``: the worker and its work horse are SIGSTOPped (a paused VM, a partitioned
  machine), ``cleanup()`` retries the job, a second worker starts it, and the first is
  continued. Reported: whether the stale attempt's end is recorded on the job while the
  retry is still running (RQ keeps one job id across retries and no attempt number).

Run: ``python benchmarks/rq_recovery.py [--monitoring-interval 1] [--scenario kill|pause|both]
[--output benchmarks/results/rq_recovery.json]``. It sleeps most of the time (about 1 minute
for ``kill``, 2.5 for ``pause``); it prints one JSON object per scenario and appends them to
``--output``. The results and what follows from them are in docs/service.md ("Lost workers").
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from redis import Redis
from rq import Queue, Retry
from rq.job import Job
from rq.registry import StartedJobRegistry

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from service.processes import children_of  # noqa: E402
from service.redis_server import RedisServer, find_redis_server  # noqa: E402

QUEUE = "rq-recovery"

_WORKER = """
import sys
from redis import Redis
from rq import Queue, Worker
connection = Redis.from_url(sys.argv[1])
queue = Queue(sys.argv[2], connection=connection)
Worker([queue], connection=connection, job_monitoring_interval=int(sys.argv[3])).work(
    burst=True, logging_level="WARNING"
)
"""


def _start_worker(url: str, interval: int) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", _WORKER, url, QUEUE, str(interval)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def _signal_worker(worker: subprocess.Popen, signum: int) -> None:
    """Send ``signum`` to the worker and to its work horse (RQ puts the horse in a process
    group of its own, so a signal to the worker's group misses it)."""
    for pid in [worker.pid, *children_of(worker.pid)]:
        os.kill(pid, signum)


def _wait_for(predicate, timeout: float, step: float = 0.1) -> float:
    """Seconds until ``predicate()`` holds; raises TimeoutError after ``timeout``."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout:
            raise TimeoutError
        time.sleep(step)
    return time.monotonic() - start


def _status(job: Job) -> str:
    return job.get_status(refresh=True)


def _sweep_until_requeued(job: Job, registry: StartedJobRegistry, timeout: float) -> float:
    """Call ``cleanup()`` every second until the job leaves 'started'; seconds it took."""
    start = time.monotonic()
    while _status(job) == "started":
        if time.monotonic() - start > timeout:
            raise TimeoutError("cleanup() never retried the job")
        registry.cleanup()
        time.sleep(1.0)
    return time.monotonic() - start


def kill_scenario(connection: Redis, url: str, interval: int) -> dict:
    queue = Queue(QUEUE, connection=connection)
    registry = StartedJobRegistry(QUEUE, connection=connection)
    job = queue.enqueue(time.sleep, 600, retry=Retry(max=1), job_timeout=900)
    worker = _start_worker(url, interval)
    _wait_for(lambda: _status(job) == "started", 30)
    time.sleep(2.0)
    ((_, expires),) = connection.zrange(registry.key, 0, -1, withscores=True)
    _signal_worker(worker, signal.SIGKILL)
    worker.wait()
    killed = time.monotonic()
    entry_left = expires - time.time()  # the registry entry's score is its expiry time
    detected = _sweep_until_requeued(job, registry, timeout=600)
    return {
        "scenario": "kill",
        "job_monitoring_interval": interval,
        "registry_entry_expires_in_s_at_kill": round(entry_left, 1),
        "seconds_from_kill_to_requeued": round(time.monotonic() - killed, 1),
        "sweep_seconds": round(detected, 1),
        "status_after": _status(job),
        "retries_left": Job.fetch(job.id, connection=connection).retries_left,
    }


def pause_scenario(connection: Redis, url: str, interval: int) -> dict:
    queue = Queue(QUEUE, connection=connection)
    registry = StartedJobRegistry(QUEUE, connection=connection)
    # The job sleeps longer than the registry entry lives, so that the retry overlaps it.
    duration = interval + 75
    job = queue.enqueue(time.sleep, duration, retry=Retry(max=1), job_timeout=900)
    first = _start_worker(url, interval)
    _wait_for(lambda: _status(job) == "started", 30)
    time.sleep(2.0)
    _signal_worker(first, signal.SIGSTOP)
    paused = time.monotonic()
    _sweep_until_requeued(job, registry, timeout=600)
    requeued = time.monotonic() - paused
    second = _start_worker(url, interval)
    _wait_for(lambda: _status(job) == "started", 30)
    _signal_worker(first, signal.SIGCONT)
    continued = time.monotonic()
    # The first work horse's sleep is long past its deadline: it returns at once.
    first.wait(timeout=120)
    first_done = time.monotonic() - continued
    status_when_first_ended = _status(job)
    second_still_running = second.poll() is None
    second.wait(timeout=duration + 60)
    results = Job.fetch(job.id, connection=connection).results()
    return {
        "scenario": "pause",
        "job_monitoring_interval": interval,
        "seconds_from_pause_to_requeued": round(requeued, 1),
        "seconds_from_continue_to_stale_attempt_ended": round(first_done, 1),
        "job_status_when_stale_attempt_ended": status_when_first_ended,
        "retry_still_running_then": second_still_running,
        "results_recorded_for_the_one_job": len(results),
        "result_types": [str(result.type) for result in results],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--monitoring-interval", type=int, default=1)
    parser.add_argument("--scenario", choices=("kill", "pause", "both"), default="both")
    parser.add_argument(
        "--output", type=Path, default=None, help="Also write the runs here (JSON)."
    )
    args = parser.parse_args()
    runs = []
    server = RedisServer(persistence_dir=None, binary=find_redis_server(prefer_path=True))
    server.start()
    try:
        connection = Redis.from_url(server.url)
        scenarios = ("kill", "pause") if args.scenario == "both" else (args.scenario,)
        for name in scenarios:
            connection.flushall()
            run = kill_scenario if name == "kill" else pause_scenario
            runs.append(run(connection, server.url, args.monitoring_interval))
            print(json.dumps(runs[-1]), flush=True)
    finally:
        server.stop()
    if args.output is not None:
        previous = json.loads(args.output.read_text()) if args.output.exists() else []
        args.output.write_text(json.dumps(previous + runs, indent=1) + "\n")


if __name__ == "__main__":
    main()
