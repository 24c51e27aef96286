"""Load check of the MoJu service on loopback (a script, not a test).

    python benchmarks/service_load.py [--jobs 50] [--workers 2] [--connections 8]

What it does, bounded in count and time (it stops by itself, at the latest after
``--timeout`` seconds):

1. starts the whole service like ``moju serve`` (embedded Redis, ``--workers`` worker
   processes, the API) on a free loopback port, with a throwaway data directory;
2. submits ``--jobs`` small jobs at once (face1, 300 points, 10 frames; one seed each) from
   as many client threads, using :class:`service.client.MojuClient`;
3. while the jobs run, polls ``GET /v1/jobs/{id}`` of random jobs over ``--connections``
   keep-alive connections as fast as the server answers, timing every request;
4. checks that every job finished with a stored result (none lost), stops the service, and
   prints and saves its figures to ``benchmarks/results/service_load.json`` with a plot
   ``service_load.png``.

The poller is a minimal asyncio HTTP/1.1 client rather than httpx: on a 2-core machine
shared with two solving workers, a heavier client would measure mostly itself.

Exit status 0 when the targets hold: every job finished with its result, and polling
sustained at least ``--min-rps`` requests/s (on average and in every whole second) with a
p99 latency under ``--max-p99-ms``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import random
import shutil
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # run from a checkout without installing

from moju_core.datasets import make_sequence  # noqa: E402
from moju_core.io import Measurements, write_measurements  # noqa: E402
from service.client import MojuClient  # noqa: E402
from service.processes import free_port  # noqa: E402
from service.states import TERMINAL_STATES  # noqa: E402
from service.supervisor import ServeOptions, Supervisor  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"


@dataclass
class PollLog:
    """Every status request: when it ended (monotonic s), its latency (s) and HTTP status;
    and when each job was first seen in a terminal state."""

    ended: list[float] = field(default_factory=list)
    latency: list[float] = field(default_factory=list)
    status: list[int] = field(default_factory=list)
    terminal_at: dict[str, float] = field(default_factory=dict)


_TERMINAL = tuple(f'"status":"{status.value}"'.encode() for status in TERMINAL_STATES)


async def _poll_connection(
    port: int, paths: list[str], stop: threading.Event, log: PollLog
) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        while not stop.is_set():
            path = random.choice(paths)
            request = f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
            started = time.perf_counter()
            writer.write(request.encode())
            head = await reader.readuntil(b"\r\n\r\n")
            lines = head.split(b"\r\n")
            length = next(
                int(line.split(b":", 1)[1])
                for line in lines
                if line.lower().startswith(b"content-length:")
            )
            body = await reader.readexactly(length)
            now = time.perf_counter()
            log.latency.append(now - started)
            log.ended.append(time.monotonic())
            log.status.append(int(lines[0].split()[1]))
            # The polled resources double as the completion record: a separate tracker
            # listing all jobs would add load of its own to what is measured.
            if path not in log.terminal_at and any(mark in body for mark in _TERMINAL):
                log.terminal_at[path] = time.monotonic()
    finally:
        writer.close()


def poll_until(
    port: int, paths: list[str], connections: int, stop: threading.Event, log: PollLog
) -> None:
    """Poll job resources over ``connections`` keep-alive connections until ``stop``."""

    async def run() -> None:
        await asyncio.gather(
            *(_poll_connection(port, paths, stop, log) for _ in range(connections))
        )

    asyncio.run(run())


def percentile_ms(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q) * 1000) if values.size else float("nan")


def plot(figures: dict, log: PollLog, finish_times: list[float], t0: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ended = np.asarray(log.ended) - t0
    latency_ms = np.asarray(log.latency) * 1000
    fig, (ax_rate, ax_latency) = plt.subplots(1, 2, figsize=(11, 4))
    if ended.size:
        seconds = np.arange(0, np.ceil(ended.max()) + 1)
        counts, _ = np.histogram(ended, bins=seconds)
        ax_rate.step(seconds[:-1], counts, where="post", label="status requests / s")
    ax_rate.axhline(figures["targets"]["min_rps"], color="grey", ls=":", label="target")
    ax_jobs = ax_rate.twinx()
    finished = np.sort(np.asarray(finish_times) - t0)
    ax_jobs.step(finished, np.arange(1, finished.size + 1), where="post", color="C1",
                 label="jobs finished")  # fmt: skip
    ax_rate.set_xlabel("time since submission (s)")
    ax_rate.set_ylabel("requests per second")
    ax_jobs.set_ylabel("jobs finished")
    ax_rate.legend(loc="upper left")
    ax_jobs.legend(loc="lower right")
    ax_rate.set_title(f"{figures['jobs']['submitted']} jobs, {figures['workers']} workers")
    if latency_ms.size:
        ax_latency.hist(latency_ms, bins=60, log=True)
    p99 = figures["polling"]["p99_ms"]
    ax_latency.axvline(p99, color="C3", label=f"p99 {p99:.1f} ms")
    ax_latency.set_xlabel("status request latency (ms)")
    ax_latency.set_ylabel("requests")
    ax_latency.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=50, help="jobs submitted at once")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    parser.add_argument("--connections", type=int, default=8, help="polling connections")
    parser.add_argument("--points", type=int, default=300, help="points per job")
    parser.add_argument(
        "--worker-niceness", type=int, default=0, help="MOJU_WORKER_NICENESS of the workers"
    )
    parser.add_argument("--timeout", type=float, default=300.0, help="give up after (s)")
    parser.add_argument("--min-rps", type=float, default=500.0, help="polling target")
    parser.add_argument("--max-p99-ms", type=float, default=50.0, help="latency target")
    parser.add_argument("--output-dir", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if not 1 <= args.jobs <= 500 or not 1 <= args.workers <= 16:
        parser.error("keep it bounded: 1..500 jobs, 1..16 workers")

    work = Path(tempfile.mkdtemp(prefix="moju-load-"))
    sequence = make_sequence("face1", n_points=args.points)
    input_path = write_measurements(work / "input.npz", Measurements(W=sequence.W))
    port = free_port()
    supervisor = Supervisor(
        ServeOptions(
            port=port,
            workers=args.workers,
            data_dir=work / "data",
            grace=1.0,
            log_level="warning",
            extra_env={"MOJU_WORKER_NICENESS": str(args.worker_niceness)},
        )
    )
    deadline = time.monotonic() + args.timeout
    base_url = supervisor.start()
    print(f"service on {base_url}, {args.workers} workers, data in {work}")
    stop_polling = threading.Event()
    log = PollLog()
    try:
        with MojuClient(base_url) as client:
            while client._http.get("/readyz").json().get("workers") != args.workers:
                if time.monotonic() > deadline:
                    raise TimeoutError("workers did not register")
                time.sleep(0.2)

        # 1. Submit every job at once, one client thread each.
        def submit(seed: int) -> tuple[str, float]:
            started = time.perf_counter()
            with MojuClient(base_url) as own:
                job = own.submit(input_path, {"seed": seed})
            return str(job.id), time.perf_counter() - started

        t0 = time.monotonic()
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            submitted = list(pool.map(submit, range(args.jobs)))
        submit_seconds = time.monotonic() - t0
        job_ids = [job_id for job_id, _ in submitted]
        print(f"submitted {len(job_ids)} jobs in {submit_seconds:.2f} s")

        # 2. Poll while the jobs run, until every job was seen ended.
        paths = [f"/v1/jobs/{job_id}" for job_id in job_ids]
        poller = threading.Thread(
            target=poll_until, args=(port, paths, args.connections, stop_polling, log)
        )
        poll_started = time.monotonic()
        poller.start()
        while len(log.terminal_at) < len(paths) and time.monotonic() < deadline:
            time.sleep(0.1)
        poll_ended = time.monotonic()
        stop_polling.set()
        poller.join(timeout=30)
        finish_times = {path.rsplit("/", 1)[1]: t for path, t in log.terminal_at.items()}

        with MojuClient(base_url) as client:
            # 3. None lost: every job finished and its result is stored.
            final = {job_id: client.get(job_id) for job_id in job_ids}
        statuses: dict[str, int] = {}
        for job in final.values():
            statuses[job.status.value] = statuses.get(job.status.value, 0) + 1
        with_result = sum(
            (work / "data" / "jobs" / job_id / "result.h5").is_file() for job_id in job_ids
        )
        run_seconds = [
            (job.ended_at - job.started_at).total_seconds()
            for job in final.values()
            if job.started_at and job.ended_at
        ]
    finally:
        stop_polling.set()
        supervisor.stop()
        shutil.rmtree(work, ignore_errors=True)

    window = np.asarray(log.ended)
    in_window = (window >= poll_started) & (window <= poll_ended)
    latency = np.asarray(log.latency)[in_window]
    errors = int(sum(code != 200 for code in np.asarray(log.status)[in_window]))
    duration = poll_ended - poll_started
    whole_seconds = np.arange(poll_started, poll_ended - 1.0 + 1e-9, 1.0)
    per_second = [int(((window >= a) & (window < a + 1.0)).sum()) for a in whole_seconds]
    figures = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        "workers": args.workers,
        "worker_niceness": args.worker_niceness,
        "jobs": {
            "submitted": len(job_ids),
            "finished": statuses.get("finished", 0),
            "statuses": statuses,
            "with_result_file": with_result,
            "lost": len(job_ids) - with_result,
            "points": args.points,
            "frames": sequence.W.shape[0] // 2,
            "submit_all_seconds": round(submit_seconds, 3),
            "submit_latency_ms_p50": percentile_ms(np.array([s for _, s in submitted]), 50),
            "submit_latency_ms_max": percentile_ms(np.array([s for _, s in submitted]), 100),
            "all_finished_after_seconds": round(max(finish_times.values()) - t0, 3)
            if finish_times
            else None,
            "job_run_seconds_mean": round(float(np.mean(run_seconds)), 3) if run_seconds else None,
        },
        "polling": {
            "connections": args.connections,
            "duration_seconds": round(duration, 3),
            "requests": int(latency.size),
            "errors": errors,
            "requests_per_second": round(latency.size / duration, 1) if duration else 0.0,
            "slowest_second_requests": min(per_second) if per_second else 0,
            "p50_ms": round(percentile_ms(latency, 50), 2),
            "p95_ms": round(percentile_ms(latency, 95), 2),
            "p99_ms": round(percentile_ms(latency, 99), 2),
            "max_ms": round(percentile_ms(latency, 100), 2),
        },
        "targets": {"min_rps": args.min_rps, "max_p99_ms": args.max_p99_ms},
    }
    passed = (
        figures["jobs"]["finished"] == len(job_ids)
        and figures["jobs"]["lost"] == 0
        and errors == 0
        and figures["polling"]["requests_per_second"] >= args.min_rps
        and figures["polling"]["slowest_second_requests"] >= args.min_rps
        and figures["polling"]["p99_ms"] < args.max_p99_ms
    )
    figures["passed"] = passed

    args.output_dir.mkdir(parents=True, exist_ok=True)
    json_path = args.output_dir / "service_load.json"
    json_path.write_text(json.dumps(figures, indent=2) + "\n")
    plot(figures, log, list(finish_times.values()), t0, args.output_dir / "service_load.png")
    print(json.dumps(figures, indent=2))
    print(f"{'PASS' if passed else 'FAIL'}; figures in {json_path}")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
