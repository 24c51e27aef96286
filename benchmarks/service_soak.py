"""Soak check of the MoJu service on loopback (a script, not a test).

    python benchmarks/service_soak.py [--minutes 3] [--workers 2] [--clients 3] [--kill-every 60]
    python benchmarks/service_soak.py --chaos [--kills 9] [--seed 0]   (see service_chaos.py)

For a few minutes, client threads send a mix of requests to a service with API keys (two
keys, one configured as a digest) and a per-key queue limit: good jobs (npz, HDF5 and CSV
uploads of a 300-point face with varied iteration caps and seeds), bad submissions (pickled
arrays, NaN, an odd number of rows, one frame, unknown or impossible parameters, a broken
CSV, the wrong content type, an oversized body, no key, a wrong key) and jobs cancelled at a
random moment (queued or running). With ``--kill-every S`` a busy worker is killed with
SIGKILL together with its work horse every S seconds (and replaced), to measure how long a
lost worker takes to be noticed with the heartbeat settings given. Then it stops submitting,
waits for every accepted job to end, and checks the invariants:

* every accepted job ended (finished, failed or cancelled); none is left queued or running;
* every finished job's result reads back and equals the solver's result for its input and
  parameters, computed here;
* no answer was a 5xx, and every bad submission got the 4xx it deserves (429 is accepted
  for submissions, after which the client waits for Retry-After);
* a job of one key is a 404 for the other key;
* no orphaned files: every job directory belongs to a job that still has a record, cancelled
  jobs have none, no temporary file is left anywhere, only finished jobs have a result;
  no queue slot, lease or running entry is left in Redis;
* the API keys appear in no log.

Bounded: at most 15 minutes of load and 8 clients; everything runs on 127.0.0.1 (a throwaway
``redis-server`` with an append-only file, ``--workers`` worker processes, the API under
uvicorn) and is stopped at the end. Figures go to ``benchmarks/results/service_soak.json``;
exit status 1 when an invariant fails.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import random
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # run from a checkout without installing

from moju_core import reconstruct  # noqa: E402
from moju_core.datasets import make_sequence  # noqa: E402
from moju_core.io import Measurements, read_result, write_measurements  # noqa: E402
from moju_core.params import SolverParams  # noqa: E402
from service.auth import key_digest  # noqa: E402
from service.processes import children_of, free_port, stop_process  # noqa: E402
from service.redis_server import RedisServer  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
LONG_PARAMS = {"max_iter": 10_000, "tol": 0.0, "rho_growth": 1.0005, "rho_max": 1e12}
#: A job of several seconds that runs to its end: what the worker kills aim at.
SLOW_PARAMS = {"max_iter": 2000, "tol": 0.0, "rho_growth": 1.01, "rho_max": 1e12, "seed": 0}
GOOD_ITERATIONS = (20, 50, 100, 200)
GOOD_SEEDS = (0, 1, 2)
TERMINAL = {"finished", "failed", "cancelled"}
UPLOAD_LIMIT = 4 * 2**20


# ------------------------------------------------------------------------------------------
# What the clients send


def _npz(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


@dataclass(frozen=True)
class Inputs:
    """The good input in three formats, and the bad submissions with their expected code."""

    good: dict[str, tuple[str, bytes]]
    bad: list[tuple[str, dict, int]]


def make_inputs(work: Path, n_points: int) -> tuple[Inputs, np.ndarray]:
    W = make_sequence("face1", n_points=n_points).W
    good = {}
    for suffix in ("npz", "h5", "csv"):
        path = write_measurements(work / f"tracks.{suffix}", Measurements(W=W))
        good[suffix] = (path.name, path.read_bytes())
    pickled = np.empty(W.shape, dtype=object)
    pickled[:] = 1.0
    with_nan = W.copy()
    with_nan[3, 5] = np.nan
    npz = good["npz"][1]

    def upload(content: bytes, name: str = "t.npz", params: object = None) -> dict:
        data = {} if params is None else {"params": json.dumps(params)}
        return {"files": {"file": (name, content)}, "data": data}

    csv_text = good["csv"][1].decode().splitlines()
    csv_text[2] = "0,1,abc,1.0"
    bad = [
        ("pickled npz", upload(_npz(W=pickled)), 422),
        ("NaN", upload(_npz(W=with_nan)), 422),
        ("odd rows", upload(_npz(W=W[:-1])), 422),
        ("one frame", upload(_npz(W=W[:2])), 422),
        ("unknown parameter", upload(npz, params={"max_itr": 5}), 422),
        ("impossible n_groups", upload(npz, params={"n_groups": 5000}), 422),
        ("absurd max_iter", upload(npz, params={"max_iter": -3}), 422),
        ("broken CSV", upload("\n".join(csv_text).encode(), "t.csv"), 422),
        ("garbage bytes", upload(os.urandom(3000), "t.bin"), 422),
        ("wrong content type", {"content": b"W,1,2", "headers": {"content-type": "text/csv"}}, 415),
        ("oversized body", upload(b"\x00" * (UPLOAD_LIMIT + 1024)), 413),
    ]
    return Inputs(good=good, bad=bad), W


# ------------------------------------------------------------------------------------------
# Book-keeping shared by the threads


@dataclass
class Job:
    job_id: str
    key: str
    kind: str  # "good", "slow" (good, but several seconds) or "cancel"
    params: dict
    submitted: float
    cancel_requested: bool = False
    deleted: bool = False  # DELETE came after it ended: removed for good
    final: dict | None = None


@dataclass
class Book:
    lock: threading.Lock = field(default_factory=threading.Lock)
    jobs: dict[str, Job] = field(default_factory=dict)
    codes: Counter = field(default_factory=Counter)
    by_kind: Counter = field(default_factory=Counter)
    server_errors: list[str] = field(default_factory=list)
    wrong_answers: list[str] = field(default_factory=list)
    submit_ms: list[float] = field(default_factory=list)
    get_ms: list[float] = field(default_factory=list)
    throttled: int = 0
    kills: list[dict] = field(default_factory=list)

    def answer(self, what: str, response: httpx.Response, started: float, into: list) -> None:
        elapsed = (time.perf_counter() - started) * 1000
        with self.lock:
            self.codes[response.status_code] += 1
            into.append(elapsed)
            if response.status_code >= 500:
                self.server_errors.append(f"{what}: {response.status_code} {response.text[:200]}")

    def wrong(self, message: str) -> None:
        with self.lock:
            self.wrong_answers.append(message)


# ------------------------------------------------------------------------------------------
# Processes


class Service:
    """Redis, the API and the workers, each a child process on loopback."""

    def __init__(self, work: Path, args: argparse.Namespace, keys: list[str]) -> None:
        self.work = work
        self.args = args
        self.redis = RedisServer(persistence_dir=work / "redis")
        self.port = free_port()
        self.env: dict[str, str] = {}
        self.api: subprocess.Popen | None = None
        self.workers: list[subprocess.Popen] = []
        self.worker_logs: dict[int, Path] = {}
        self.keys = keys
        self.logs = work / "logs"
        self.logs.mkdir()
        self._started = 0

    def start(self) -> str:
        redis_url = self.redis.start()
        env = {k: v for k, v in os.environ.items() if not k.startswith("MOJU_")}
        env.update(
            PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")])),
            MOJU_REDIS_URL=redis_url,
            MOJU_DATA_DIR=str(self.work / "data"),
            MOJU_API_KEYS=f"{self.keys[0]},sha256:{key_digest(self.keys[1])}",
            MOJU_MAX_QUEUED_JOBS_PER_KEY=str(self.args.queue_limit),
            MOJU_MAX_UPLOAD_BYTES=str(UPLOAD_LIMIT),
            MOJU_HEARTBEAT_INTERVAL=str(self.args.heartbeat_interval),
            MOJU_HEARTBEAT_TTL=str(self.args.heartbeat_ttl),
            MOJU_LOST_JOB_RETRIES=str(self.args.lost_job_retries),
            MOJU_WORKER_NICENESS=str(self.args.worker_niceness),
        )
        self.env = env
        for _ in range(self.args.workers):
            self.workers.append(self.start_worker())
        command = [
            sys.executable,
            "-m",
            "uvicorn",
            "--factory",
            "service.app:create_app",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--log-level",
            "info",
        ]
        with open(self.logs / "api.log", "wb") as log:
            self.api = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)
        base = f"http://127.0.0.1:{self.port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                ready = httpx.get(f"{base}/readyz", timeout=2)
                if ready.status_code == 200 and ready.json()["workers"] >= self.args.workers:
                    return base
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        raise RuntimeError("the service did not become ready within 60 s")

    def start_worker(self) -> subprocess.Popen:
        self._started += 1
        path = self.logs / f"worker-{self._started}.log"
        with open(path, "wb") as log:
            process = subprocess.Popen(
                [sys.executable, "-m", "worker"],
                env=self.env,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        self.worker_logs[process.pid] = path
        return process

    def stop(self) -> None:
        if self.api is not None:
            stop_process(self.api, timeout=10)
        for worker in self.workers:
            if worker.poll() is None:
                worker.send_signal(signal.SIGTERM)
        time.sleep(1.2)  # RQ ignores a second SIGTERM within a second: this one is cold
        for worker in self.workers:
            stop_process(worker, timeout=10)
        self.redis.stop()


def current_job(log_path: Path) -> str | None:
    """The job a worker started last, from its log ("job <id>: started (attempt n, ...")."""
    found = re.findall(
        r"job ([0-9a-f-]{36}): started \(attempt", log_path.read_text(errors="replace")
    )
    return found[-1] if found else None


# ------------------------------------------------------------------------------------------
# Threads


def client_loop(
    index: int,
    base: str,
    keys: list[str],
    inputs: Inputs,
    book: Book,
    stop: threading.Event,
    seed: int,
) -> None:
    rng = random.Random(seed + index)
    key = keys[index % len(keys)]
    auth = {"Authorization": f"Bearer {key}"}
    with httpx.Client(base_url=base, timeout=60) as http:
        while not stop.is_set():
            roll = rng.random()
            if roll < 0.47:
                submit_good(http, auth, key, inputs, book, rng, kind="good")
            elif roll < 0.55:
                submit_good(http, auth, key, inputs, book, rng, kind="slow")
            elif roll < 0.70:
                submit_good(http, auth, key, inputs, book, rng, kind="cancel")
            elif roll < 0.92:
                name, request, expected = rng.choice(inputs.bad)
                book.by_kind[f"bad: {name}"] += 1
                started = time.perf_counter()
                request = dict(request)
                headers = {**auth, **request.pop("headers", {})}
                response = http.post("/v1/jobs", headers=headers, **request)
                book.answer(f"bad {name}", response, started, book.submit_ms)
                if response.status_code != expected or "detail" not in response.json():
                    book.wrong(f"{name}: {response.status_code} {response.text[:200]}")
            elif roll < 0.96:
                # No key, or a wrong one.
                headers = rng.choice([{}, {"Authorization": f"Bearer {secrets.token_hex(20)}"}])
                book.by_kind["bad: no or wrong key"] += 1
                started = time.perf_counter()
                response = http.get("/v1/jobs", headers=headers)
                book.answer("no key", response, started, book.get_ms)
                if response.status_code != 401:
                    book.wrong(f"no/wrong key: {response.status_code}")
            else:
                # Another key's job must not be found.
                with book.lock:
                    others = [j.job_id for j in book.jobs.values() if j.key != key]
                if others:
                    book.by_kind["other key's job"] += 1
                    started = time.perf_counter()
                    response = http.get(f"/v1/jobs/{rng.choice(others)}", headers=auth)
                    book.answer("other key", response, started, book.get_ms)
                    if response.status_code != 404:
                        book.wrong(f"other key's job: {response.status_code}")
            stop.wait(rng.uniform(0.3, 1.2))


def submit_good(
    http: httpx.Client,
    auth: dict,
    key: str,
    inputs: Inputs,
    book: Book,
    rng: random.Random,
    *,
    kind: str,
) -> None:
    file_format = rng.choice(sorted(inputs.good))
    name, content = inputs.good[file_format]
    if kind == "good":
        params = {"max_iter": rng.choice(GOOD_ITERATIONS), "seed": rng.choice(GOOD_SEEDS)}
    elif kind == "slow":
        params = dict(SLOW_PARAMS)
    else:
        params = dict(LONG_PARAMS)
    started = time.perf_counter()
    response = http.post(
        "/v1/jobs",
        headers=auth,
        files={"file": (name, content)},
        data={"params": json.dumps(params)},
    )
    book.answer(f"submit {kind}", response, started, book.submit_ms)
    if response.status_code == 429:
        with book.lock:
            book.throttled += 1
        time.sleep(min(float(response.headers.get("retry-after", "5")), 10.0))
        return
    if response.status_code != 202:
        book.wrong(f"good {file_format} upload: {response.status_code} {response.text[:200]}")
        return
    job = Job(response.json()["id"], key, kind, params, time.monotonic())
    with book.lock:
        book.jobs[job.job_id] = job
        book.by_kind[f"{kind} ({file_format})"] += 1
    if kind == "cancel":
        time.sleep(rng.uniform(0.0, 4.0))  # queued or running, whichever it is by then
        started = time.perf_counter()
        current = http.get(f"/v1/jobs/{job.job_id}", headers=auth)
        book.answer("get", current, started, book.get_ms)
        response = http.delete(f"/v1/jobs/{job.job_id}", headers=auth)
        book.answer("delete", response, started, book.get_ms)
        if response.status_code != 204:
            book.wrong(f"cancel: {response.status_code} {response.text[:200]}")
        with book.lock:
            job.cancel_requested = True
            ended_before = current.status_code == 200 and current.json()["status"] in TERMINAL
            job.deleted = ended_before


def checker_loop(base: str, book: Book, stop: threading.Event) -> None:
    """Reads every job that has not ended yet, about once a second."""
    with httpx.Client(base_url=base, timeout=60) as http:
        while not stop.wait(1.0):
            with book.lock:
                pending = [j for j in book.jobs.values() if j.final is None and not j.deleted]
            for job in pending:
                started = time.perf_counter()
                response = http.get(
                    f"/v1/jobs/{job.job_id}", headers={"Authorization": f"Bearer {job.key}"}
                )
                book.answer("get", response, started, book.get_ms)
                if response.status_code == 404 and job.cancel_requested:
                    job.deleted = True  # ended just before its DELETE: removed
                elif response.status_code == 200 and response.json()["status"] in TERMINAL:
                    job.final = response.json()


def _slow_target(service: Service, book: Book, connection) -> tuple | None:
    """A worker running a 'slow' job (running for a second at least), with its horses."""
    for worker in service.workers:
        if worker.poll() is not None:
            continue
        horses = children_of(worker.pid)
        job_id = current_job(service.worker_logs[worker.pid])
        job = book.jobs.get(job_id) if job_id else None
        if not horses or job is None or job.kind != "slow":
            continue
        status, attempts, started = connection.hmget(
            f"moju:job:{job_id}", "status", "attempts", "started_at"
        )
        if status == b"running" and started and time.time() - float(started) > 1.0:
            return worker, horses, job_id, attempts
    return None


def chaos_loop(
    service: Service, redis_url: str, every: float, book: Book, stop: threading.Event
) -> None:
    """Every ``every`` s: SIGKILL a worker running a slow job, and its work horse; start a
    replacement, and time how long the job takes to leave the lost worker."""
    from redis import Redis

    connection = Redis.from_url(redis_url)
    while not stop.wait(every):
        target = None
        while target is None and not stop.wait(0.5):
            target = _slow_target(service, book, connection)
        if target is None:
            break
        worker, horses, job_id, attempts = target
        os.kill(worker.pid, signal.SIGKILL)
        for horse in horses:
            os.kill(horse, signal.SIGKILL)
        killed_at = time.monotonic()
        worker.wait()
        service.workers[service.workers.index(worker)] = service.start_worker()
        record = {"job_id": job_id, "detected_after_s": None, "then": None}
        while job_id and time.monotonic() - killed_at < 180:
            fields = connection.hmget(f"moju:job:{job_id}", "status", "attempts")
            status = fields[0].decode() if fields[0] else None
            if status != "running" or fields[1] != attempts:
                record["detected_after_s"] = round(time.monotonic() - killed_at, 2)
                # "running" again: queued and already taken by another worker.
                record["then"] = "queued again" if status in ("queued", "running") else status
                break
            time.sleep(0.2)
        with book.lock:
            book.kills.append(record)
        print(f"killed a worker running job {job_id}: {record}", flush=True)
    connection.close()


# ------------------------------------------------------------------------------------------
# Checks


def percentiles(values: list[float]) -> dict[str, float]:
    if not values:
        return {}
    array = np.asarray(values)
    return {f"p{q}": round(float(np.percentile(array, q)), 1) for q in (50, 95, 99)} | {
        "max": round(float(array.max()), 1)
    }


def verify(base: str, book: Book, service: Service, W: np.ndarray) -> dict:
    from redis import Redis

    problems: list[str] = []
    data = service.work / "data" / "jobs"
    statuses = Counter()
    references: dict[str, np.ndarray] = {}
    finished_checked = 0
    retried = 0
    with httpx.Client(base_url=base, timeout=60) as http:
        for job in book.jobs.values():
            if job.deleted:
                statuses["deleted after it ended"] += 1
                if (data / job.job_id).exists():
                    problems.append(f"{job.job_id}: deleted but its files remain")
                continue
            final = job.final or {}
            status = final.get("status", "not ended")
            statuses[status] += 1
            retried += final.get("attempts", 0) > 1
            if status not in TERMINAL:
                problems.append(f"{job.job_id}: still {status}")
                continue
            if job.kind == "cancel" and status not in ("cancelled", "failed"):
                problems.append(f"{job.job_id}: cancelled job ended {status}")
            if status == "failed" and not (final.get("error") or "").startswith("worker lost"):
                # Good input: only a worker killed on each of its attempts may fail it.
                problems.append(f"{job.job_id}: failed: {final.get('error')}")
            names = (
                sorted(p.name for p in (data / job.job_id).iterdir())
                if (data / job.job_id).is_dir()
                else None
            )
            if status == "cancelled" and names is not None:
                problems.append(f"{job.job_id}: cancelled but files remain: {names}")
            if status == "failed" and names is not None and names != ["input.npz"]:
                problems.append(f"{job.job_id}: failed but holds {names}")
            if status != "finished":
                continue
            response = http.get(
                f"/v1/jobs/{job.job_id}/result",
                params={"format": "npz"},
                headers={"Authorization": f"Bearer {job.key}"},
            )
            if response.status_code != 200:
                problems.append(f"{job.job_id}: result answered {response.status_code}")
                continue
            path = service.work / "downloaded.npz"
            path.write_bytes(response.content)
            result = read_result(path)
            combo = json.dumps(job.params, sort_keys=True)
            if combo not in references:
                references[combo] = reconstruct(W, SolverParams(**job.params)).shapes
            if result.metadata.get("job_id") != job.job_id or not np.allclose(
                result.shapes, references[combo], rtol=0, atol=1e-9
            ):
                problems.append(f"{job.job_id}: its result differs from the solver's")
            finished_checked += 1
    # No orphans: every directory is a known job with a record; no temporary file anywhere.
    redis = Redis.from_url(service.env["MOJU_REDIS_URL"])
    for directory in data.iterdir():
        if not redis.exists(f"moju:job:{directory.name}"):
            problems.append(f"orphaned directory {directory.name}")
        for entry in directory.iterdir():
            if entry.name.endswith(".tmp"):
                problems.append(f"temporary file left: {directory.name}/{entry.name}")
            if (
                entry.name.startswith("result")
                and book.jobs.get(directory.name)
                and ((book.jobs[directory.name].final or {}).get("status") != "finished")
            ):
                problems.append(f"result of an unfinished job: {directory.name}")
    leftovers = {
        "running": redis.zcard("moju:running"),
        "leases": len(list(redis.scan_iter(match="moju:lease:*"))),
        "queue slots": sum(redis.zcard(k) for k in redis.scan_iter(match="moju:active*")),
    }
    for name, count in leftovers.items():
        if count:
            problems.append(f"{count} {name} left in Redis")
    redis.close()
    # The keys appear in no log.
    for log in service.logs.iterdir():
        text = log.read_text(errors="replace")
        for key in service.keys:
            if key in text or key_digest(key) in text:
                problems.append(f"an API key appears in {log.name}")
    return {
        "statuses": dict(statuses),
        "finished_results_checked": finished_checked,
        "jobs_retried_after_a_lost_worker": int(retried),
        "reference_results_computed": len(references),
        "problems": problems,
    }


# ------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=3.0, help="minutes of load")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--clients", type=int, default=3, help="client threads")
    parser.add_argument("--points", type=int, default=300)
    parser.add_argument(
        "--kill-every",
        type=float,
        default=0.0,
        help="SIGKILL a busy worker every this many seconds (0: never)",
    )
    parser.add_argument("--heartbeat-interval", type=float, default=5.0)
    parser.add_argument("--heartbeat-ttl", type=float, default=30.0)
    parser.add_argument("--lost-job-retries", type=int, default=1)
    parser.add_argument("--queue-limit", type=int, default=8, help="per-key queue limit")
    parser.add_argument("--worker-niceness", type=int, default=10)
    parser.add_argument("--drain-timeout", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, default=None)
    chaos = parser.add_argument_group("chaos (a real moju serve; see service_chaos.py)")
    chaos.add_argument("--chaos", action="store_true", help="SIGKILL Redis, workers and the API")
    chaos.add_argument("--kills", type=int, default=9, help="SIGKILLs spread over the run")
    chaos.add_argument("--frames", type=int, default=20, help="frames of the tiny chaos jobs")
    chaos.add_argument("--compare", type=int, default=5, help="results checked by a direct solve")
    args = parser.parse_args(argv)
    if args.chaos:
        from service_chaos import RESULTS as CHAOS_RESULTS
        from service_chaos import chaos_main

        if not (0 < args.minutes <= 15 and 1 <= args.kills <= 60):
            parser.error("keep it bounded: up to 15 minutes and 60 kills")
        args.output = args.output or CHAOS_RESULTS / "service_chaos.json"
        return chaos_main(args)
    args.output = args.output or RESULTS / "service_soak.json"
    if not (0 < args.minutes <= 15 and 1 <= args.clients <= 8 and 1 <= args.workers <= 8):
        parser.error("keep it bounded: up to 15 minutes, 8 clients, 8 workers")

    work = Path(tempfile.mkdtemp(prefix="moju-soak-"))
    keys = [secrets.token_urlsafe(24) for _ in range(2)]
    inputs, W = make_inputs(work, args.points)
    service = Service(work, args, keys)
    book = Book()
    stop_load, stop_checker = threading.Event(), threading.Event()
    load_before = os.getloadavg()
    try:
        base = service.start()
        print(
            f"service on {base} with {args.workers} workers; load for {args.minutes} min",
            flush=True,
        )
        started = time.monotonic()
        threads = [
            threading.Thread(
                target=client_loop, args=(i, base, keys, inputs, book, stop_load, args.seed)
            )
            for i in range(args.clients)
        ]
        checker = threading.Thread(target=checker_loop, args=(base, book, stop_checker))
        if args.kill_every > 0:
            threads.append(
                threading.Thread(
                    target=chaos_loop,
                    args=(service, service.env["MOJU_REDIS_URL"], args.kill_every, book, stop_load),
                )
            )
        for thread in [*threads, checker]:
            thread.start()
        stop_load.wait(args.minutes * 60)
        stop_load.set()
        for thread in threads:
            thread.join(timeout=240)
        load_seconds = time.monotonic() - started
        print(f"load stopped after {load_seconds:.0f} s; draining", flush=True)
        drain_deadline = time.monotonic() + args.drain_timeout
        while time.monotonic() < drain_deadline:
            with book.lock:
                pending = [j for j in book.jobs.values() if j.final is None and not j.deleted]
            if not pending:
                break
            time.sleep(1.0)
        drained_after = time.monotonic() - started - load_seconds
        stop_checker.set()
        checker.join(timeout=60)
        checks = verify(base, book, service, W)
    finally:
        stop_load.set()
        stop_checker.set()
        service.stop()
        shutil.rmtree(work, ignore_errors=True)

    finished = checks["statuses"].get("finished", 0)
    problems = (
        checks["problems"]
        + [f"5xx: {e}" for e in book.server_errors]
        + [f"unexpected answer: {w}" for w in book.wrong_answers]
    )
    detections = [
        k["detected_after_s"] for k in book.kills if k["then"] in ("queued again", "failed")
    ]
    figures = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "load_average_before": [round(x, 2) for x in load_before],
            "load_average_after": [round(x, 2) for x in os.getloadavg()],
        },
        "settings": {
            "minutes": args.minutes,
            "workers": args.workers,
            "clients": args.clients,
            "points": args.points,
            "kill_every_s": args.kill_every,
            "heartbeat_interval_s": args.heartbeat_interval,
            "heartbeat_ttl_s": args.heartbeat_ttl,
            "lost_job_retries": args.lost_job_retries,
            "queue_limit_per_key": args.queue_limit,
            "worker_niceness": args.worker_niceness,
        },
        "load_seconds": round(load_seconds, 1),
        "drain_seconds": round(drained_after, 1),
        "requests": {
            "total": sum(book.codes.values()),
            "by_status": {str(k): v for k, v in sorted(book.codes.items())},
            "server_errors": len(book.server_errors),
            "unexpected_answers": len(book.wrong_answers),
            "throttled_429": book.throttled,
            "by_kind": dict(sorted(book.by_kind.items())),
            "submit_ms": percentiles(book.submit_ms),
            "get_ms": percentiles(book.get_ms),
        },
        "jobs": {
            "accepted": len(book.jobs),
            **checks,
            "finished_per_minute": round(finished / (load_seconds / 60), 1),
        },
        "worker_kills": {
            "count": len(book.kills),
            "detected_after_s": detections,
            "detected_after_s_max": max(detections) if detections else None,
            "outcomes": [k["then"] for k in book.kills],
        },
        "problems": problems,
        "passed": not problems,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(figures, indent=2) + "\n")
    print(json.dumps(figures, indent=2))
    print(f"{'PASS' if not problems else 'FAIL'}; figures in {args.output}")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
