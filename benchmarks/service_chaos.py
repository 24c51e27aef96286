"""Chaos soak of a real ``moju serve``: random SIGKILLs of Redis, a worker and the API.

    python benchmarks/service_soak.py --chaos [--minutes 4] [--kills 9] [--seed 0] [--workers 2]

One ``moju serve`` (embedded Redis, ``--workers`` workers, the API) runs on loopback with a
throwaway data directory. Client threads submit tiny jobs (npz uploads of a small face, a few
iterations) and follow them; meanwhile ``--kills`` SIGKILLs, spread over the run, each hit a
child chosen at random (seeded) among Redis, the workers and the API. The clients tolerate the
outages: a 503, a 429 or a refused connection is retried with exponential backoff (reads
also after a dropped connection or a timeout). A submission whose answer was lost (the
connection dropped after the upload was sent) has an unknown outcome; the API has no
idempotency key, so every submission carries a unique file name and such submissions are
resolved at the end by listing the jobs and matching the name (found, or counted apart as
having made no job). After the load, the run waits for every job to end and checks:

* no job lost: every job the API accepted with a 202 still has a record, and no job exists
  that its client was not told about (other than one found for a lost answer);
* every job terminal (finished, or failed by the lease rules after its worker was killed);
* results correct: every finished result has shapes ``(F, P, 3)``, all finite, and for a few
  jobs it equals a direct ``reconstruct`` of the same input and parameters;
* nothing orphaned: every job directory has a record; after SIGINT to ``moju serve`` no
  process it ever had (children and work horses) is alive;
* the time from each SIGKILL to ``/readyz`` answering 200 again with the killed child
  replaced (target: 30 s).

Figures go to ``benchmarks/results/service_chaos.json``; exit status 1 when an invariant fails.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from moju_core import reconstruct  # noqa: E402
from moju_core.datasets import make_sequence  # noqa: E402
from moju_core.io import read_result  # noqa: E402
from moju_core.params import SolverParams  # noqa: E402
from service.processes import children_of, descendants, free_port  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
TERMINAL = {"finished", "failed", "cancelled"}
ITERATIONS = (10, 20, 40)
READY_TARGET_S = 30.0
#: Answers after which a request is tried again (the service is restarting a child).
RETRY_CODES = {502, 503, 504}


# ------------------------------------------------------------------------------------------
# Book-keeping


@dataclass
class Submission:
    name: str  # unique upload file name: how a lost answer is found again
    params: dict
    job_ids: list[str] = field(default_factory=list)
    unknown: int = 0  # attempts whose answer was lost
    refused: Counter = field(default_factory=Counter)  # 503s, dropped connections
    final: dict[str, dict] = field(default_factory=dict)


@dataclass
class Book:
    lock: threading.Lock = field(default_factory=threading.Lock)
    submissions: list[Submission] = field(default_factory=list)
    codes: Counter = field(default_factory=Counter)
    transport_errors: Counter = field(default_factory=Counter)
    server_errors: list[str] = field(default_factory=list)
    kills: list[dict] = field(default_factory=list)
    seen_pids: set[int] = field(default_factory=set)


def request(
    http: httpx.Client, book: Book, method: str, url: str, *, patience: float = 120, **kwargs
) -> httpx.Response | None:
    """One request, tried again with backoff (0.2 s doubling to 4 s) on a 5xx or a transport
    error for up to ``patience`` s; None when it never got an answer."""
    delay, deadline = 0.2, time.monotonic() + patience
    while True:
        try:
            response = http.request(method, url, **kwargs)
            with book.lock:
                book.codes[response.status_code] += 1
            if response.status_code not in RETRY_CODES:
                if response.status_code >= 500:
                    with book.lock:
                        book.server_errors.append(f"{method} {url}: {response.status_code}")
                return response
        except httpx.TransportError as error:
            with book.lock:
                book.transport_errors[type(error).__name__] += 1
        if time.monotonic() > deadline:
            return None
        time.sleep(delay)
        delay = min(delay * 2, 4.0)


def submit(http: httpx.Client, book: Book, content: bytes, sub: Submission) -> None:
    """POST until a 202 or an unknown outcome; 503 and refused connections are retried."""
    delay = 0.2
    for _ in range(60):
        try:
            response = http.post(
                "/v1/jobs",
                files={"file": (sub.name, content)},
                data={"params": json.dumps(sub.params)},
            )
        except (httpx.ConnectError, httpx.ConnectTimeout) as error:
            sub.refused[type(error).__name__] += 1  # never reached the API: safe to retry
        except httpx.TransportError as error:
            # Sent, answer lost: the job may exist. Resolved by name at the end, not resent.
            with book.lock:
                book.transport_errors[type(error).__name__] += 1
            sub.unknown += 1
            return
        else:
            with book.lock:
                book.codes[response.status_code] += 1
            if response.status_code == 202:
                sub.job_ids.append(response.json()["id"])
                return
            if response.status_code in (429, *RETRY_CODES):
                sub.refused[str(response.status_code)] += 1
            else:
                with book.lock:
                    book.server_errors.append(f"submit: {response.status_code} {response.text}")
                return
        time.sleep(delay)
        delay = min(delay * 2, 4.0)


def client_loop(
    index: int, base: str, content: bytes, book: Book, stop: threading.Event, seed: int
) -> None:
    rng = random.Random(seed * 1000 + index)
    with httpx.Client(base_url=base, timeout=20) as http:
        while not stop.is_set():
            params = {"max_iter": rng.choice(ITERATIONS), "seed": rng.randrange(3)}
            sub = Submission(f"chaos-{uuid.uuid4().hex}.npz", params)
            with book.lock:
                book.submissions.append(sub)
            submit(http, book, content, sub)
            stop.wait(rng.uniform(1.0, 3.0))


# ------------------------------------------------------------------------------------------
# The service and the kills


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def children_by_kind(serve_pid: int) -> dict[str, list[int]]:
    """The live children of ``moju serve``: redis, worker, api."""
    kinds: dict[str, list[int]] = {"redis": [], "worker": [], "api": []}
    for pid in children_of(serve_pid):
        line = _cmdline(pid)
        if "redis-server" in line:
            kinds["redis"].append(pid)
        elif "-m worker" in line:
            kinds["worker"].append(pid)
        elif "uvicorn" in line:
            kinds["api"].append(pid)
    return kinds


def ready(base: str) -> bool:
    try:
        return httpx.get(f"{base}/readyz", timeout=2).status_code == 200
    except httpx.TransportError:
        return False


def wait_recovered(
    base: str, serve_pid: int, kind: str, killed: int, count: int, timeout: float = 120
) -> tuple[float | None, bool]:
    """Seconds from now until the killed child is replaced and /readyz is 200; and whether
    /readyz was seen not ready in between."""
    started, seen_down = time.monotonic(), False
    while time.monotonic() - started < timeout:
        pids = children_by_kind(serve_pid)[kind]
        replaced = killed not in pids and len(pids) == count
        is_ready = ready(base)
        seen_down |= not is_ready
        if replaced and is_ready:
            return time.monotonic() - started, seen_down
        time.sleep(0.1)
    return None, seen_down


def chaos_loop(
    base: str, serve: subprocess.Popen, args: argparse.Namespace, book: Book, stop: threading.Event
) -> None:
    rng = random.Random(args.seed)
    spacing = args.minutes * 60 / (args.kills + 1)
    counts = {"redis": 1, "worker": args.workers, "api": 1}
    kinds = ["redis", "worker", "api"]
    order = [kinds[i % 3] for i in range(args.kills)]  # each kind about equally often
    rng.shuffle(order)
    for kind in order:
        if stop.wait(spacing * rng.uniform(0.6, 1.0)):
            break
        pids = children_by_kind(serve.pid)[kind]
        if not pids:
            book.kills.append({"kind": kind, "error": "no such child"})
            continue
        victim = rng.choice(pids)
        os.kill(victim, signal.SIGKILL)
        seconds, seen_down = wait_recovered(base, serve.pid, kind, victim, counts[kind])
        record = {
            "kind": kind,
            "at_s": round(time.monotonic() - book_started, 1),
            "ready_again_after_s": None if seconds is None else round(seconds, 2),
            "readyz_seen_not_ready": seen_down,
        }
        with book.lock:
            book.kills.append(record)
        print(f"SIGKILL {kind} (pid {victim}): {record}", flush=True)


def track_pids(serve_pid: int, book: Book, stop: threading.Event) -> None:
    """Every process ever below ``moju serve`` (workers' horses included), for the orphan check."""
    while not stop.wait(0.3):
        found = descendants(serve_pid)
        with book.lock:
            book.seen_pids |= found


book_started = time.monotonic()


# ------------------------------------------------------------------------------------------
# Checks


def list_all(http: httpx.Client, book: Book) -> list[dict]:
    items, offset = [], 0
    while offset is not None:
        response = request(http, book, "GET", "/v1/jobs", params={"limit": 100, "offset": offset})
        if response is None or response.status_code != 200:
            raise RuntimeError("could not list the jobs")
        page = response.json()
        items += page["items"]
        offset = page["next_offset"]
    return items


def drain(http: httpx.Client, book: Book, timeout: float) -> tuple[list[dict], float]:
    """Wait until every listed job is terminal; the listing and the seconds it took."""
    started = time.monotonic()
    while True:
        items = list_all(http, book)
        if all(item["status"] in TERMINAL for item in items):
            return items, time.monotonic() - started
        if time.monotonic() - started > timeout:
            return items, time.monotonic() - started
        time.sleep(2.0)


def _upload_name(item: dict) -> str:
    """The file name a job was uploaded with (``input.filename``), or ''."""
    return (item.get("input") or {}).get("filename") or ""


def check(
    http: httpx.Client, book: Book, items: list[dict], W: np.ndarray, data: Path, compare: int
) -> dict:
    problems: list[str] = []
    by_name: dict[str, list[dict]] = {}
    for item in items:
        by_name.setdefault(_upload_name(item), []).append(item)
    listed = {item["id"] for item in items}
    accepted = resolved_unknown = unresolved = duplicates = 0
    for sub in book.submissions:
        found = by_name.get(sub.name, [])
        for job_id in sub.job_ids:
            accepted += 1
            if job_id not in listed:
                problems.append(f"lost: job {job_id} was accepted (202) but has no record")
        extra = [item for item in found if item["id"] not in sub.job_ids]
        if sub.unknown:
            if extra:
                resolved_unknown += 1
            else:
                unresolved += 1  # the request never made a job: nothing to lose
        elif extra:
            problems.append(f"{sub.name}: a job nobody was told about: {extra[0]['id']}")
        duplicates += len(found) > 1
    statuses = Counter(item["status"] for item in items)
    for item in items:
        if item["status"] not in TERMINAL:
            problems.append(f"{item['id']}: still {item['status']}")
        elif item["status"] == "failed" and not (item.get("error") or "").startswith(
            ("worker lost", "the worker running this job")
        ):
            problems.append(f"{item['id']}: failed: {item.get('error')}")
    finished = [item for item in items if item["status"] == "finished"]
    params_of = {name: sub.params for sub in book.submissions for name in [sub.name]}
    compared = 0
    references: dict[str, np.ndarray] = {}
    F, P = W.shape[0] // 2, W.shape[1]
    for item in finished:
        response = request(
            http, book, "GET", f"/v1/jobs/{item['id']}/result", params={"format": "npz"}
        )
        if response is None or response.status_code != 200:
            problems.append(f"{item['id']}: result answered {response and response.status_code}")
            continue
        path = data.parent / "downloaded.npz"
        path.write_bytes(response.content)
        shapes = read_result(path).shapes
        if shapes.shape != (F, P, 3) or not np.isfinite(shapes).all():
            problems.append(
                f"{item['id']}: result shapes {shapes.shape}, finite "
                f"{bool(np.isfinite(shapes).all())}"
            )
            continue
        params = params_of.get(_upload_name(item))
        if params is not None and compared < compare:
            combo = json.dumps(params, sort_keys=True)
            if combo not in references:
                references[combo] = reconstruct(W, SolverParams(**params)).shapes
            if not np.allclose(shapes, references[combo], rtol=0, atol=1e-9):
                problems.append(f"{item['id']}: result differs from a direct solve")
            compared += 1
    # No job directory without a record.
    orphans = (
        [d.name for d in (data / "jobs").iterdir() if d.name not in listed]
        if (data / "jobs").is_dir()
        else []
    )
    problems += [f"job directory without a record: {name}" for name in orphans]
    return {
        "submissions": len(book.submissions),
        "accepted_202": accepted,
        "answer_lost_then_found_by_name": resolved_unknown,
        "answer_lost_no_job_made": unresolved,
        "submissions_with_two_jobs": duplicates,
        "jobs_listed": len(items),
        "statuses": dict(statuses),
        "jobs_retried": sum(1 for item in items if item.get("attempts", 1) > 1),
        "finished_results_checked": len(finished),
        "compared_with_direct_solve": compared,
        "orphaned_directories": len(orphans),
        "problems": problems,
    }


def _ours(pid: int) -> bool:
    """``pid`` is alive (not a zombie) and still one of the service's programs."""
    line = _cmdline(pid)
    return alive(pid) and (sys.executable in line or "redis-server" in line)


def alive(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return status != "Z"


# ------------------------------------------------------------------------------------------


def start_serve(work: Path, args: argparse.Namespace, port: int) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOJU_")}
    env.update(
        PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")])),
        MOJU_HEARTBEAT_INTERVAL=str(args.heartbeat_interval),
        MOJU_HEARTBEAT_TTL=str(args.heartbeat_ttl),
        MOJU_LOST_JOB_RETRIES=str(args.lost_job_retries),
    )
    command = [
        sys.executable, "-c", "from moju_cli.main import cli; cli()", "serve",
        "--port", str(port), "--workers", str(args.workers), "--data-dir", str(work / "data"),
    ]  # fmt: skip
    log = open(work / "serve.log", "wb")  # noqa: SIM115 - closed with the process
    return subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)


def write_markdown(figures: dict, path: Path) -> None:
    """A short summary of the figures (``service_chaos.md`` next to the json)."""
    settings, jobs = figures["settings"], figures["jobs"]
    lines = [
        "# Chaos soak of `moju serve`",
        "",
        f"{settings['minutes']} min of load, {settings['clients']} clients, "
        f"{settings['workers']} workers, jobs of {settings['points']} points x "
        f"{settings['frames']} frames (max_iter {settings['max_iter']}), heartbeat "
        f"{settings['heartbeat_interval_s']} s / TTL {settings['heartbeat_ttl_s']} s, seed "
        f"{settings['seed']}; {os.cpu_count()} CPUs, load average "
        f"{figures['machine']['load_average_before'][0]} before.",
        "",
        "| SIGKILL of | at (s) | /readyz 200 again after (s) |",
        "|---|---|---|",
    ]
    for kill in figures["kills"]:
        lines.append(f"| {kill['kind']} | {kill.get('at_s')} | {kill.get('ready_again_after_s')} |")
    lines += [
        "",
        f"Submissions {jobs['submissions']}: {jobs['accepted_202']} accepted with a 202, "
        f"{jobs['answer_lost_then_found_by_name']} whose answer was lost and whose job was "
        f"found by name, {jobs['answer_lost_no_job_made']} whose answer was lost and that made "
        f"no job. Jobs: {jobs['statuses']}, {jobs['jobs_retried']} run again after a lost "
        f"worker; {jobs['finished_results_checked']} results checked (shape, finite), "
        f"{jobs['compared_with_direct_solve']} equal to a direct solve. Orphaned directories: "
        f"{jobs['orphaned_directories']}; processes left after SIGINT: "
        f"{figures['processes_left_after_sigint']} of {figures['processes_seen']} seen. "
        f"Requests: {figures['requests']['by_status']}, transport errors "
        f"{figures['requests']['transport_errors']}. Drain after the load: "
        f"{figures['drain_seconds']} s.",
        "",
        f"**{'PASS' if figures['passed'] else 'FAIL'}**"
        + ("" if figures["passed"] else ": " + "; ".join(figures["problems"][:10])),
        "",
    ]
    path.write_text("\n".join(lines))


def chaos_main(args: argparse.Namespace) -> int:
    global book_started
    work = Path(tempfile.mkdtemp(prefix="moju-chaos-"))
    W = make_sequence("face1", n_frames=args.frames, n_points=args.points).W
    buffer = io.BytesIO()
    np.savez(buffer, W=W)
    content = buffer.getvalue()
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    book = Book()
    serve = start_serve(work, args, port)
    stop_load, stop_tracker = threading.Event(), threading.Event()
    load_before = os.getloadavg()
    figures: dict = {}
    problems: list[str] = []
    try:
        deadline = time.monotonic() + 120
        while not ready(base):
            if time.monotonic() > deadline or serve.poll() is not None:
                raise RuntimeError(f"moju serve did not become ready; see {work}/serve.log")
            time.sleep(0.3)
        print(f"moju serve (pid {serve.pid}) ready on {base}", flush=True)
        book_started = time.monotonic()
        tracker = threading.Thread(target=track_pids, args=(serve.pid, book, stop_tracker))
        threads = [
            threading.Thread(
                target=client_loop, args=(i, base, content, book, stop_load, args.seed)
            )
            for i in range(args.clients)
        ]
        killer = threading.Thread(target=chaos_loop, args=(base, serve, args, book, stop_load))
        for thread in [tracker, *threads, killer]:
            thread.start()
        stop_load.wait(args.minutes * 60)
        stop_load.set()
        killer.join()  # a kill in progress waits for its recovery
        for thread in threads:
            thread.join(timeout=300)
        load_seconds = time.monotonic() - book_started
        print(f"load stopped after {load_seconds:.0f} s; draining", flush=True)
        with httpx.Client(base_url=base, timeout=30) as http:
            items, drain_seconds = drain(http, book, args.drain_timeout)
            checks = check(http, book, items, W, work / "data", args.compare)
        problems += checks["problems"]
    finally:
        stop_load.set()
        serve.send_signal(signal.SIGINT)
        try:
            serve.wait(timeout=60)
        except subprocess.TimeoutExpired:
            problems.append("moju serve did not stop within 60 s of SIGINT")
            serve.kill()
            serve.wait()
        time.sleep(1.0)
        stop_tracker.set()
        leftovers = sorted(pid for pid in book.seen_pids if _ours(pid))
        problems += [f"process left after SIGINT: {pid} {_cmdline(pid)}" for pid in leftovers]
        shutil.rmtree(work, ignore_errors=True)
    problems += [f"5xx: {e}" for e in book.server_errors]
    times = [k["ready_again_after_s"] for k in book.kills if "ready_again_after_s" in k]
    slow = [t for t in times if t is None or t > READY_TARGET_S]
    problems += [f"not ready within {READY_TARGET_S:.0f} s after a kill: {t}" for t in slow]
    by_kind: dict[str, list] = {}
    for kill in book.kills:
        by_kind.setdefault(kill["kind"], []).append(kill.get("ready_again_after_s"))
    figures = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_average_before": [round(x, 2) for x in load_before],
            "load_average_after": [round(x, 2) for x in os.getloadavg()],
        },
        "settings": {
            "minutes": args.minutes,
            "kills": args.kills,
            "seed": args.seed,
            "workers": args.workers,
            "clients": args.clients,
            "points": args.points,
            "frames": args.frames,
            "max_iter": list(ITERATIONS),
            "heartbeat_interval_s": args.heartbeat_interval,
            "heartbeat_ttl_s": args.heartbeat_ttl,
            "lost_job_retries": args.lost_job_retries,
        },  # fmt: skip
        "load_seconds": round(load_seconds, 1),
        "drain_seconds": round(drain_seconds, 1),
        "requests": {
            "by_status": {str(k): v for k, v in sorted(book.codes.items())},
            "transport_errors": dict(book.transport_errors),
            "submission_retries": dict(sum((s.refused for s in book.submissions), Counter())),
        },
        "jobs": {k: v for k, v in checks.items() if k != "problems"},
        "kills": book.kills,
        "ready_again_after_s_by_kind": by_kind,
        "ready_again_after_s_max": max((t for t in times if t is not None), default=None),
        "processes_seen": len(book.seen_pids),
        "processes_left_after_sigint": len(leftovers),
        "problems": problems,
        "passed": not problems,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(figures, indent=2) + "\n")
    write_markdown(figures, args.output.with_suffix(".md"))
    print(json.dumps(figures, indent=2))
    print(f"{'PASS' if not problems else 'FAIL'}; figures in {args.output}")
    return 0 if not problems else 1
