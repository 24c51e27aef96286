"""Hostile and slow clients against ``moju serve`` on loopback (a script, not a test).

    python benchmarks/service_hostile.py [--workers 2] [--rows zeros,h5,json,slow,...]

It starts the service as ``moju serve`` does (embedded Redis, ``--workers`` workers, the API
under ``service.uvicorn_server`` with the default settings) in a throwaway data directory,
then sends, one row after the other:

1. an npz of zeros, W 4,000 x 16,000 (0.5 MB on the wire);
2. the same with ``gt`` and an int64 ``visibility``;
3. a chunked HDF5 of fill values (W, gt, visibility; 2 kB), then three of them at once;
4. a JSON body just under 4 MiB, eight at once;
5. a valid CSV of about 240 MB (1,000 frames x 15,000 points, whole-pixel coordinates);
6. a body trickled at 1 byte/s, headers trickled at 1 byte/s, an idle connection, and 2,000
   uploads trickling at once.

For each row it prints the HTTP status(es), the API process's peak growth in resident
memory over its level before the row (sampled every 20 ms from ``/proc/<pid>/status``; the
upload checks' child processes are counted apart), the worst ``/healthz`` latency seen by a
probe that asks every 0.25 s over a new connection, and for slow connections the seconds
until the server closed them. A row answered 202 is followed until its job ends (zeros and
fill values fail in the worker: ``W is zero after centring``); jobs whose solve is not the
point (the JSON and CSV rows, random tracks of 16,000 points) are deleted once accepted.
After the series it waits for the API to be idle and reports its memory against its start.

Figures go to ``benchmarks/results/service_hostile.json``; the exit status is 0 when every
target holds: each row a 4xx or an ended job, API growth at most 400 MB, /healthz within 1 s
throughout, idle memory back within 200 MB of its start, every slow connection closed within
60 s.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import http.client
import io
import json
import multiprocessing
import os
import platform
import resource
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import h5py
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # run from a checkout without installing

from service.processes import descendants, free_port  # noqa: E402
from service.supervisor import ServeOptions, Supervisor  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
MIB = 2**20
TERMINAL = ("finished", "failed", "cancelled")


def _rss(pid: int) -> int:
    """Resident memory of ``pid`` in bytes (0 when it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


class MemorySampler(threading.Thread):
    """Peak RSS of the API and (apart) of its child processes since the last :meth:`mark`."""

    def __init__(self, pid: int) -> None:
        super().__init__(daemon=True)
        self.pid = pid
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.api_peak = 0
        self.children_peak = 0

    def mark(self) -> int:
        """Start a new window; return the API's RSS now."""
        with self.lock:
            now = _rss(self.pid)
            self.api_peak, self.children_peak = now, 0
        return now

    def run(self) -> None:
        while not self.stop.wait(0.02):
            api = _rss(self.pid)
            children = sum(_rss(child) for child in descendants(self.pid))
            with self.lock:
                self.api_peak = max(self.api_peak, api)
                self.children_peak = max(self.children_peak, children)


class HealthProbe(threading.Thread):
    """``GET /healthz`` every 0.25 s over a new connection; the worst latency per window."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.worst = 0.0
        self.failures = 0
        self.count = 0

    def mark(self) -> None:
        with self.lock:
            self.worst, self.failures, self.count = 0.0, 0, 0

    def run(self) -> None:
        while not self.stop.wait(0.25):
            started = time.perf_counter()
            ok = False
            try:
                connection = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
                connection.request("GET", "/healthz")
                ok = connection.getresponse().status == 200
                connection.close()
            except OSError:
                pass
            latency = time.perf_counter() - started
            with self.lock:
                self.worst = max(self.worst, latency)
                self.count += 1
                self.failures += not ok


def _request(
    port: int, method: str, path: str, body: bytes | Path = b"", headers: dict | None = None
) -> tuple[int, dict]:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
    try:
        if isinstance(body, Path):
            with open(body, "rb") as handle:
                connection.request(method, path, body=handle, headers=headers or {})
                response = connection.getresponse()
        else:
            connection.request(method, path, body=body, headers=headers or {})
            response = connection.getresponse()
        text = response.read()
        try:
            return response.status, json.loads(text) if text else {}
        except ValueError:
            return response.status, {"raw": text[:200].decode(errors="replace")}
    finally:
        connection.close()


def _multipart(part: bytes | Path, name: str, target: Path) -> tuple[Path, dict]:
    """A multipart body with one file part, written to ``target`` (streamed when sent)."""
    boundary = "moju-hostile-boundary"
    with open(target, "wb") as out:
        out.write(
            f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n'
            "Content-Type: application/octet-stream\r\n\r\n".encode()
        )
        if isinstance(part, Path):
            with open(part, "rb") as source:
                shutil.copyfileobj(source, out, MIB)
        else:
            out.write(part)
        out.write(f"\r\n--{boundary}--\r\n".encode())
    headers = {
        "Content-Type": f"multipart/form-data; boundary={boundary}",
        "Content-Length": str(target.stat().st_size),
    }
    return target, headers


def _zeros_npz(extras: bool) -> bytes:
    arrays: dict[str, np.ndarray] = {"W": np.zeros((4000, 16000))}
    if extras:
        arrays["gt"] = np.zeros((2000, 16000, 3))
        arrays["visibility"] = np.ones((2000, 16000), dtype=np.int64)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def _fill_value_h5() -> bytes:
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as h5:
        h5.create_dataset("W", (4000, 16000), dtype="f8", chunks=(200, 1000), fillvalue=1.0)
        h5.create_dataset("gt", (2000, 16000, 3), dtype="f8", chunks=(100, 1000, 3))
        h5.create_dataset("visibility", (2000, 16000), dtype="i8", chunks=(200, 1000), fillvalue=1)
    return buffer.getvalue()


def _json_body(limit: int = 4 * MIB - 4096) -> bytes:
    """Tracks of 16 frames x P points with P as large as fits under ``limit`` bytes."""
    rng = np.random.default_rng(7)
    n_frames = 16
    for n_points in range(20_000, 1000, -500):
        tracks = np.round(rng.uniform(0, 999, size=(n_frames, n_points, 2)), 2).tolist()
        body = json.dumps({"tracks": tracks, "params": {"max_iter": 5}}).encode()
        if len(body) <= limit:
            return body
    raise RuntimeError("no JSON body fits")


def _csv_file(path: Path, n_frames: int = 1000, n_points: int = 15_000) -> Path:
    """A valid CSV (frame,point,x,y) of a rotating cloud, whole-pixel coordinates of two
    digits: about 240 MB for 1,000 frames x 15,000 points."""
    rng = np.random.default_rng(5)
    shape = rng.normal(size=(3, n_points)) * 12
    point = np.arange(n_points)
    with open(path, "w") as out:
        out.write("frame,point,x,y\n")
        for frame in range(n_frames):
            angle = 0.01 * frame
            rotation = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0]], dtype=float)
            xy = np.clip(np.round(rotation @ shape + 55), 10, 99)
            block = np.column_stack([np.full(n_points, frame), point, xy[0], xy[1]])
            np.savetxt(out, block, fmt="%d", delimiter=",")
    return path


class Bench:
    """The service, the probes and the rows' figures."""

    def __init__(self, port: int, api_pid: int, work: Path) -> None:
        self.port = port
        self.api_pid = api_pid
        self.work = work
        self.memory = MemorySampler(api_pid)
        self.health = HealthProbe(port)
        self.rows: list[dict[str, Any]] = []
        self.memory.start()
        self.health.start()

    def row(self, name: str, action: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        before = self.memory.mark()
        self.health.mark()
        started = time.monotonic()
        figures = action()
        figures.update(
            row=name,
            seconds=round(time.monotonic() - started, 1),
            api_before_mib=round(before / MIB, 1),
            api_growth_mib=round((self.memory.api_peak - before) / MIB, 1),
            checks_peak_mib=round(self.memory.children_peak / MIB, 1),
            healthz_worst_s=round(self.health.worst, 3),
            healthz_failures=self.health.failures,
            healthz_probes=self.health.count,
        )
        self.rows.append(figures)
        print(json.dumps(figures), flush=True)
        return figures

    def wait_job(self, job_id: str, timeout: float = 600) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            status, job = _request(self.port, "GET", f"/v1/jobs/{job_id}")
            if status == 200 and job["status"] in TERMINAL:
                return job
            time.sleep(0.5)
        return {"status": "still running after the benchmark's wait", "error": None}

    def upload(self, part: bytes | Path, name: str) -> tuple[int, dict]:
        body, headers = _multipart(part, name, Path(tempfile.mktemp(dir=self.work)))
        try:
            return _request(self.port, "POST", "/v1/jobs", body, headers)
        finally:
            body.unlink()

    def upload_rows(self, part: bytes | Path, name: str, at_once: int, follow: bool) -> dict:
        with ThreadPoolExecutor(at_once) as pool:
            answers = list(pool.map(lambda _: self.upload(part, name), range(at_once)))
        statuses = [status for status, _ in answers]
        ended = []
        for status, body in answers:
            if status != 202:
                continue
            if follow:
                job = self.wait_job(body["id"])
                ended.append(f"{job['status']}: {str(job.get('error'))[:80]}")
            else:
                _request(self.port, "DELETE", f"/v1/jobs/{body['id']}")
                ended.append("accepted, then deleted (solve not timed)")
        detail = next((body.get("detail") for _, body in answers if "detail" in body), None)
        return {
            "statuses": statuses,
            "detail": detail[:200] if detail else None,
            "jobs": ended,
            "wire_bytes": part.stat().st_size if isinstance(part, Path) else len(part),
        }


async def _slow_connection(port: int, kind: str, interval: float, limit: float) -> float:
    """Seconds until the server closed a connection that never completes its request."""
    started = time.monotonic()
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    if kind == "body":
        writer.write(
            b"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000\r\n"
            b"Content-Type: multipart/form-data; boundary=b\r\n\r\n"
        )
    trickle = {"body": b"--b\r\n" + b"x" * 100_000, "headers": b"POST /v1/jobs HTTP/1.1\r\n"}
    data = trickle.get(kind, b"")

    async def closed() -> None:
        with contextlib.suppress(ConnectionError):
            while await reader.read(65536):
                pass

    reading = asyncio.create_task(closed())
    position = 0
    while not reading.done() and time.monotonic() - started < limit:
        if kind != "idle" and position < len(data):
            with contextlib.suppress(ConnectionError):
                writer.write(data[position : position + 1])
            position += 1
        await asyncio.sleep(interval)
    if not reading.done():
        reading.cancel()
        writer.close()
        return float("inf")
    writer.close()
    return time.monotonic() - started


def _slow_rows(port: int, many: int, limit: float) -> dict:
    async def run() -> dict:
        single = await asyncio.gather(
            *(_slow_connection(port, kind, 1.0, limit) for kind in ("body", "headers", "idle"))
        )
        kinds = ["body", "headers", "idle"]
        crowd = await asyncio.gather(
            *(_slow_connection(port, "body", 1.0, limit) for _ in range(many))
        )
        return {
            "closed_after_s": {kind: round(t, 1) for kind, t in zip(kinds, single, strict=True)},
            "trickling_uploads": many,
            "trickling_closed": sum(t != float("inf") for t in crowd),
            "trickling_slowest_close_s": round(max(crowd), 1),
        }

    return asyncio.run(run())


#: The rows of the table, by the name --rows knows them.
ROWS = ("zeros", "zeros-extras", "h5", "h5x3", "json", "csv", "slow")


def _slow_rows_apart(port: int, many: int, limit: float) -> dict:
    """:func:`_slow_rows` in a process of its own: thousands of clients in this one would
    starve the /healthz probe's thread of the GIL and time the client, not the server."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=context) as pool:
        return pool.submit(_slow_rows, port, many, limit).result()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--trickling", type=int, default=2000)
    parser.add_argument(
        "--rows",
        default=",".join(ROWS),
        help=f"comma-separated rows to run, of {', '.join(ROWS)} (default: all)",
    )
    args = parser.parse_args()
    rows = set(args.rows.split(","))
    if not rows <= set(ROWS):
        parser.error(f"unknown rows {sorted(rows - set(ROWS))}; rows are {', '.join(ROWS)}")
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, max(soft, 3 * args.trickling)), hard))

    work = Path(tempfile.mkdtemp(prefix="moju-hostile-"))
    port = free_port()
    supervisor = Supervisor(
        ServeOptions(
            port=port, workers=args.workers, data_dir=work / "data", grace=1.0, log_level="warning"
        )
    )
    print("preparing inputs ...", flush=True)
    zeros = _zeros_npz(extras=False) if "zeros" in rows else b""
    zeros_extras = _zeros_npz(extras=True) if "zeros-extras" in rows else b""
    fill = _fill_value_h5()
    body = _json_body() if "json" in rows else b""
    csv_path = _csv_file(work / "tracks.csv") if "csv" in rows else None
    base_url = supervisor.start()
    assert supervisor.api is not None
    time.sleep(3)  # let the API settle before its starting memory is read
    bench = Bench(port, supervisor.api.pid, work)
    start_rss = _rss(bench.api_pid)
    print(f"service on {base_url}; API pid {bench.api_pid} at {start_rss / MIB:.0f} MiB")
    try:
        if "zeros" in rows:
            bench.row(
                "npz of zeros, W 4000 x 16000",
                lambda: bench.upload_rows(zeros, "zeros.npz", 1, follow=True),
            )
        if "zeros-extras" in rows:
            bench.row(
                "npz of zeros with gt and int64 visibility",
                lambda: bench.upload_rows(zeros_extras, "zeros.npz", 1, follow=True),
            )
        if "h5" in rows:
            bench.row(
                "chunked HDF5 of fill values (W, gt, visibility)",
                lambda: bench.upload_rows(fill, "fill.h5", 1, follow=True),
            )
        if "h5x3" in rows:
            bench.row(
                "the same HDF5, three at once",
                lambda: bench.upload_rows(fill, "fill.h5", 3, follow=True),
            )

        def json_row() -> dict:
            with ThreadPoolExecutor(8) as pool:
                answers = list(
                    pool.map(
                        lambda _: _request(
                            port, "POST", "/v1/jobs", body, {"Content-Type": "application/json"}
                        ),
                        range(8),
                    )
                )
            for status, answer in answers:
                if status == 202:
                    _request(port, "DELETE", f"/v1/jobs/{answer['id']}")
            return {
                "statuses": [s for s, _ in answers],
                "wire_bytes": len(body),
                "jobs": ["accepted, then deleted (solve not timed)"] * 8,
            }

        if "json" in rows:
            bench.row("JSON body just under 4 MiB, 8 at once", json_row)
        if csv_path is not None:
            csv_row = lambda: bench.upload_rows(csv_path, "tracks.csv", 1, follow=False)  # noqa: E731
            bench.row("valid CSV, 1000 frames x 15000 points", csv_row)
        if "slow" in rows:
            bench.row(
                "slow connections (1 byte/s) and trickling uploads",
                lambda: _slow_rows_apart(port, args.trickling, limit=120.0),
            )
        time.sleep(5)
        idle_rss = _rss(bench.api_pid)
    finally:
        bench.memory.stop.set()
        bench.health.stop.set()
        supervisor.stop()
        shutil.rmtree(work, ignore_errors=True)

    idle_growth = (idle_rss - start_rss) / MIB
    rows = bench.rows
    targets = {
        "every row a 4xx or an ended job": all(
            all(s == 202 or 400 <= s < 500 for s in row.get("statuses", [202]))
            and all("still running" not in job for job in row.get("jobs", []))
            for row in rows
        ),
        "API growth <= 400 MB": all(row["api_growth_mib"] * MIB <= 400e6 for row in rows),
        "/healthz within 1 s": all(
            row["healthz_worst_s"] <= 1.0 and row["healthz_failures"] == 0 for row in rows
        ),
        "idle memory within 200 MB of start": idle_growth * MIB <= 200e6,
        "slow connections closed within 60 s": all(
            max(row["closed_after_s"].values()) <= 60
            and row["trickling_closed"] == row["trickling_uploads"]
            and row["trickling_slowest_close_s"] <= 60
            for row in rows
            if "closed_after_s" in row
        ),
    }
    summary = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_average_at_end": os.getloadavg(),
        },
        "workers": args.workers,
        "api_start_mib": round(start_rss / MIB, 1),
        "api_idle_after_mib": round(idle_rss / MIB, 1),
        "api_idle_growth_mib": round(idle_growth, 1),
        "rows": rows,
        "targets": targets,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "service_hostile.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"API idle: {start_rss / MIB:.0f} MiB at start, {idle_rss / MIB:.0f} MiB after")
    for target, held in targets.items():
        print(f"{'ok  ' if held else 'FAIL'} {target}")
    return 0 if all(targets.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
