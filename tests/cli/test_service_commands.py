"""``moju serve``, ``moju worker`` and ``moju submit``.

The end-to-end test runs the real commands as processes: ``moju serve`` with its embedded
Redis and a worker, ``moju submit --wait -o``, then Ctrl-C (SIGINT) with a job still running,
and checks that no process of the service survives; a second ``moju serve`` on the same data
directory still knows the jobs (Redis's append-only file).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from api_thread import serving
from click.testing import CliRunner

from moju_cli.service_commands import _parse_param, submit, worker
from moju_core.datasets import make_sequence
from moju_core.io import Measurements, write_measurements
from service.processes import descendants, free_port
from worker.runner import INTERRUPTED

REPO = Path(__file__).resolve().parents[2]
TERMINAL = ("finished", "failed", "cancelled")
LONG_PARAMS = ["max_iter=10000", "tol=0.0", "rho_growth=1.0005", "rho_max=1e12"]


def moju_command() -> list[str]:
    """The ``moju`` console script, or the same entry point through the interpreter."""
    script = shutil.which("moju")
    if script is not None:
        return [script]
    return [sys.executable, "-c", "import sys; from moju_cli.main import cli; sys.exit(cli())"]


def service_environment(**extra: str) -> dict[str, str]:
    """This environment without MOJU_* settings (so ``moju serve`` embeds its own Redis),
    plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOJU_")}
    env.update(extra)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[-1].split()[0] != "Z"


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _parent(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()[1])
    except OSError:
        return -1


class Served:
    """A ``moju serve`` process on a free port."""

    def __init__(self, data_dir: Path, log_path: Path, **env: str) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path
        with open(log_path, "ab") as log:
            self.process = subprocess.Popen(
                [*moju_command(), "serve", "--port", str(self.port), "--workers", "1",
                 "--data-dir", str(data_dir), "--grace", "1"],
                env=service_environment(**env),
                cwd=REPO,
                stdout=log,
                stderr=subprocess.STDOUT,
            )  # fmt: skip
        deadline = time.monotonic() + 60
        while True:
            assert self.process.poll() is None, f"moju serve exited:\n{self.log()}"
            assert time.monotonic() < deadline, f"moju serve never became ready:\n{self.log()}"
            try:
                if httpx.get(f"{self.url}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.2)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def child(self, marker: str) -> int:
        """PID of the one child whose command line contains ``marker``."""
        found = [
            pid
            for pid in descendants(self.process.pid)
            if alive(pid) and marker in _cmdline(pid) and _parent(pid) == self.process.pid
        ]
        assert len(found) == 1, f"{marker}: {found}"
        return found[0]

    def wait_for_log(self, text: str, timeout: float = 60) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.log():
            assert time.monotonic() < deadline, f"never logged {text!r}:\n{self.log()}"
            time.sleep(0.1)

    def wait_ready(self, timeout: float = 60) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, f"not ready again:\n{self.log()}"
            time.sleep(0.2)

    def stop(self, sig: int = signal.SIGINT, timeout: float = 30) -> int:
        self.process.send_signal(sig)
        return self.process.wait(timeout=timeout)


def run_moju(*arguments: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*moju_command(), *arguments],
        env=service_environment(),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process checks use /proc")
def test_serve_submit_and_ctrl_c_leaves_no_process(tmp_path: Path) -> None:
    sequence = make_sequence("face1", n_points=300)
    small = write_measurements(tmp_path / "small.npz", Measurements(W=sequence.W))
    long_input = write_measurements(
        tmp_path / "long.npz", Measurements(W=make_sequence("face1", n_points=2000).W)
    )
    data_dir = tmp_path / "data"
    served = Served(data_dir, tmp_path / "serve.log")
    try:
        done = run_moju(
            "submit", str(small), "--server", served.url, "--param", "max_iter=60",
            "--wait", "-o", str(tmp_path / "out.npz"),
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        assert "finished: 60 iterations, stopped: max_iter iterations reached" in done.stdout
        assert "finished finished" not in done.stderr  # the bar names the end once
        with np.load(tmp_path / "out.npz") as result:
            assert result["shapes"].shape == (10, 300, 3)
        finished_id = done.stdout.split()[1]

        queued = run_moju("submit", str(long_input), "--server", served.url,
                          *(f"--param={p}" for p in LONG_PARAMS))  # fmt: skip
        assert queued.returncode == 0, queued.stderr
        long_id = queued.stdout.split()[1]
        deadline = time.monotonic() + 30
        while httpx.get(f"{served.url}/v1/jobs/{long_id}").json()["status"] != "running":
            assert time.monotonic() < deadline
            time.sleep(0.1)

        tree = descendants(served.process.pid)
        assert len(tree) >= 4  # redis-server, worker, its work horse, uvicorn
        started = time.monotonic()
        assert served.stop(signal.SIGINT) == 0, served.log()
        assert time.monotonic() - started < 20
        survivors = {pid for pid in tree if alive(pid)}
        assert not survivors, f"left running: {survivors}"
    finally:
        if served.process.poll() is None:
            served.process.kill()

    # Restarted on the same data directory, the service remembers both jobs.
    again = Served(data_dir, tmp_path / "serve.log")
    try:
        jobs = httpx.get(f"{again.url}/v1/jobs").json()
        statuses = {job["id"]: (job["status"], job["error"]) for job in jobs["items"]}
        assert statuses[finished_id] == ("finished", None)
        assert statuses[long_id] == ("failed", INTERRUPTED)
        response = httpx.get(f"{again.url}/v1/jobs/{finished_id}/result?format=npz")
        assert response.status_code == 200
        assert again.stop(signal.SIGTERM) == 0
    finally:
        if again.process.poll() is None:
            again.process.kill()


#: A few seconds of work on the 300-point face: long enough to be killed mid-way.
MEDIUM_PARAMS = {"max_iter": 1500, "tol": 0.0, "rho_growth": 1.01, "rho_max": 1e12}


def _submit(url: str, path: Path, params: dict) -> str:
    with open(path, "rb") as handle:
        answer = httpx.post(
            f"{url}/v1/jobs",
            files={"file": (path.name, handle)},
            data={"params": json.dumps(params)},
            timeout=30,
        )
    assert answer.status_code == 202, answer.text
    return answer.json()["id"]


def _wait_job(url: str, job_id: str, done, timeout: float = 120) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        try:
            job = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=5).json()
            if done(job):
                return job
        except httpx.TransportError:
            pass  # the API is restarting
        assert time.monotonic() < deadline, f"job {job_id} never got there"
        time.sleep(0.1)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process checks use /proc")
def test_serve_restarts_killed_worker_redis_and_api(tmp_path: Path) -> None:
    """SIGKILL of each child of ``moju serve`` in turn: it comes back, no job is lost."""
    path = write_measurements(
        tmp_path / "w.npz", Measurements(W=make_sequence("face1", n_points=300).W)
    )
    # The job killed mid-way solves 2,000 points: 1,500 iterations of the 300 take under a
    # second, and the job could finish before the worker is killed.
    long_path = write_measurements(
        tmp_path / "long.npz", Measurements(W=make_sequence("face1", n_points=2_000).W)
    )
    fast_leases = {"MOJU_HEARTBEAT_INTERVAL": "0.5", "MOJU_HEARTBEAT_TTL": "2"}
    served = Served(tmp_path / "data", tmp_path / "serve.log", **fast_leases)
    seen: set[int] = set()
    try:
        # A worker killed mid-job (as the out-of-memory killer would): its orphaned work
        # horse is killed, a new worker starts, and the job runs again and finishes.
        running = _submit(served.url, long_path, MEDIUM_PARAMS)
        queued = _submit(served.url, path, {"max_iter": 20})
        _wait_job(served.url, running, lambda j: (j["progress"] or {}).get("iteration", 0) >= 3)
        worker_pid = served.child("-m worker")
        seen |= {worker_pid, *descendants(worker_pid)}
        os.kill(worker_pid, signal.SIGKILL)
        served.wait_for_log(f"worker 1 (pid {worker_pid}) exited with signal SIGKILL")
        served.wait_for_log("left behind by worker 1")
        served.wait_for_log("worker 1 started again")
        again = _wait_job(served.url, running, lambda j: j["status"] in TERMINAL)
        assert (again["status"], again["attempts"]) == ("finished", 2), again
        assert _wait_job(served.url, queued, lambda j: j["status"] in TERMINAL)["status"] == (
            "finished"
        )

        # Redis killed: started again on the same port from its append-only file.
        redis_pid = served.child("redis-server")
        seen.add(redis_pid)
        os.kill(redis_pid, signal.SIGKILL)
        served.wait_for_log(f"Redis (pid {redis_pid}) exited with signal SIGKILL")
        served.wait_for_log("Redis started again")
        served.wait_ready()
        assert httpx.get(f"{served.url}/v1/jobs/{running}").json()["status"] == "finished"
        after_redis = _submit(served.url, path, {"max_iter": 20})
        job = _wait_job(served.url, after_redis, lambda j: j["status"] in TERMINAL)
        assert job["status"] == "finished", job

        # The API killed: started again; the jobs are still there.
        api_pid = served.child("uvicorn")
        seen.add(api_pid)
        os.kill(api_pid, signal.SIGKILL)
        served.wait_for_log(f"the API (pid {api_pid}) exited with signal SIGKILL")
        served.wait_for_log("the API started again")
        served.wait_ready()
        after_api = _submit(served.url, path, {"max_iter": 20})
        job = _wait_job(served.url, after_api, lambda j: j["status"] in TERMINAL)
        assert job["status"] == "finished", job
        assert httpx.get(f"{served.url}/v1/jobs").json()["total"] == 4

        seen |= descendants(served.process.pid)
        assert served.stop(signal.SIGINT) == 0, served.log()
        assert not {pid for pid in seen if alive(pid)}
    finally:
        if served.process.poll() is None:
            served.process.kill()


def test_submit_refuses_bad_parameters_before_uploading(tmp_path: Path) -> None:
    path = tmp_path / "w.npz"
    np.savez(path, W=np.zeros((4, 5)))
    runner = CliRunner()
    unreachable = f"http://127.0.0.1:{free_port()}"

    result = runner.invoke(submit, [str(path), "--server", unreachable, "--param", "max_itr=3"])
    assert result.exit_code == 2
    assert "unknown parameter 'max_itr'" in result.output

    result = runner.invoke(submit, [str(path), "--server", unreachable, "--param", "max_iter"])
    assert result.exit_code == 2 and "is not key=value" in result.output

    result = runner.invoke(submit, [str(path), "--server", unreachable, "-o", "out.txt"])
    assert result.exit_code == 2 and ".npz, .h5 or .hdf5" in result.output

    params = tmp_path / "params.json"
    params.write_text('{"max_iter": 5, "method": "sdg"}')
    result = runner.invoke(
        submit, [str(path), "--server", unreachable, "--params-json", str(params)]
    )
    assert result.exit_code == 1
    assert "could not reach the MoJu server" in result.output


def test_parameter_values_are_typed() -> None:
    assert _parse_param("max_iter=100") == ("max_iter", 100)
    assert _parse_param("tol=1e-8") == ("tol", 1e-8)
    assert _parse_param("method=sdg") == ("method", "sdg")
    assert _parse_param("n_groups=null") == ("n_groups", None)


def test_worker_without_redis_says_how_to_configure(isolated_settings) -> None:
    result = CliRunner().invoke(worker, ["--burst"])
    assert result.exit_code == 1
    assert "MOJU_REDIS_URL is not set" in result.output and "--redis-url" in result.output


@pytest.fixture
def isolated_settings(monkeypatch: pytest.MonkeyPatch):
    """Undo what the commands export to os.environ and cache, after the test."""
    from service.settings import get_settings

    for name in ("MOJU_REDIS_URL", "MOJU_DATA_DIR", "MOJU_QUEUE_NAME", "MOJU_WORKER_THREADS"):
        monkeypatch.setenv(name, "placeholder")  # recorded, so restored (or removed) later
        monkeypatch.delenv(name)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in handlers.items():  # RQ's worker installs its own
        signal.signal(sig, handler)
    get_settings.cache_clear()


def test_worker_burst_runs_queued_jobs(redis_url: str, tmp_path: Path, isolated_settings) -> None:
    """``moju worker --burst`` empties the queue and exits (in-process, forking horses)."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    settings = Settings(redis_url=redis_url, data_dir=tmp_path, cleanup_interval=0)
    tracks = make_sequence("face1", n_points=200).W.reshape(10, 2, 200).transpose(0, 2, 1)
    with TestClient(create_app(settings)) as client:
        job = client.post("/v1/jobs", json={"tracks": tracks.tolist(), "params": {"max_iter": 9}})
        job_id = job.json()["id"]
        result = CliRunner().invoke(
            worker, ["--burst", "--redis-url", redis_url, "--data-dir", str(tmp_path)]
        )
        assert result.exit_code == 0, result.output
        final = client.get(f"/v1/jobs/{job_id}").json()
    assert final["status"] == "finished" and final["result"]["n_iter"] == 9


def test_api_key_makes_a_key_and_its_entry() -> None:
    from moju_cli.service_commands import api_key
    from service.auth import ApiKeys

    made = CliRunner().invoke(api_key, [])
    assert made.exit_code == 0, made.output
    lines = dict(line.split(":", 1) for line in made.output.splitlines())
    key, entry = lines["key"].strip(), lines["entry"].strip()
    assert len(key) >= 32 and entry.startswith("sha256:") and key not in entry
    keys = ApiKeys.from_entries([(entry, "test")])
    assert keys.owner_of(key) is not None and keys.owner_of(key + "x") is None
    hashed = CliRunner().invoke(api_key, ["--hash", key])
    assert hashed.output.strip() == entry


def test_submit_sends_the_api_key(redis_url: str, tmp_path: Path, monkeypatch) -> None:
    from pydantic import SecretStr

    from service.auth import key_digest
    from service.settings import Settings

    key = "cli-test-key-0123456789abcdef"
    settings = Settings(redis_url=redis_url, data_dir=tmp_path / "data", cleanup_interval=0)
    settings = settings.model_copy(update={"api_keys": SecretStr(f"sha256:{key_digest(key)}")})
    with serving(settings) as url:
        path = write_measurements(
            tmp_path / "w.npz", Measurements(W=make_sequence("face1", n_points=50).W)
        )
        monkeypatch.delenv("MOJU_API_KEY", raising=False)
        refused = CliRunner().invoke(submit, [str(path), "--server", url])
        assert refused.exit_code == 1
        assert "HTTP 401: this server needs an API key" in refused.output
        accepted = CliRunner().invoke(submit, [str(path), "--server", url],
                                      env={"MOJU_API_KEY": key})  # fmt: skip
        assert accepted.exit_code == 0, accepted.output
        assert "queued (10 frames x 50 points)" in accepted.output
        assert key not in accepted.output


def test_submit_sends_a_mask(redis_url: str, tmp_path: Path) -> None:
    """--mask goes to the server as the upload's 'mask' part (here refused: no video)."""
    from service.settings import Settings

    settings = Settings(redis_url=redis_url, data_dir=tmp_path / "data", cleanup_interval=0)
    path = write_measurements(
        tmp_path / "w.npz", Measurements(W=make_sequence("face1", n_points=50).W)
    )
    mask = tmp_path / "mask.png"
    mask.write_bytes(b"\x89PNG\r\n\x1a\n")
    with serving(settings) as url:
        answer = CliRunner().invoke(submit, [str(path), "--server", url, "--mask", str(mask)])
    assert answer.exit_code == 1
    assert "a 'mask' goes with a video upload only" in answer.output


def test_submit_sends_the_camera(redis_url: str, tmp_path: Path) -> None:
    """--focal and --intrinsics go to the server as the 'focal' and 'intrinsics' fields; both
    together, or a file that is no K, are refused before anything is uploaded."""
    from service.client import MojuClient
    from service.settings import Settings

    settings = Settings(redis_url=redis_url, data_dir=tmp_path / "data", cleanup_interval=0)
    W = make_sequence("face1", n_points=50).W * 100 + 300  # pixels of a 640 x 480 frame
    path = write_measurements(tmp_path / "w.npz", Measurements(W=W, frame_size=(640, 480)))
    k_file = tmp_path / "K.txt"
    k_file.write_text("500, 0, 320\n0, 510, 240\n0, 0, 1\n")
    with serving(settings) as url:
        focal = CliRunner().invoke(submit, [str(path), "--server", url, "--focal", "800"])
        given = CliRunner().invoke(
            submit, [str(path), "--server", url, "--intrinsics", str(k_file)]
        )
        with MojuClient(url) as client:
            cameras = [job.input.camera for job in client.list_jobs().items]
    assert focal.exit_code == 0, focal.output
    assert "camera: focal 800 x 800 px, principal point (319.5, 239.5) (from --focal)" in (
        focal.output
    )
    assert given.exit_code == 0, given.output
    assert "camera: focal 500 x 510 px, principal point (320, 240) (from --intrinsics)" in (
        given.output
    )
    assert [(camera.source, camera.K[0][0], camera.K[1][2]) for camera in cameras] == [
        ("intrinsics", 500.0, 240.0),  # newest first
        ("focal", 800.0, 239.5),
    ]

    unreachable = "http://127.0.0.1:9"
    both = CliRunner().invoke(
        submit, [str(path), "--server", unreachable, "--focal", "800", "--intrinsics", str(k_file)]
    )
    assert both.exit_code == 2
    assert "--intrinsics and --focal both give the camera" in both.output
    k_file.write_text("500, 0, 320\n0, 510, 240\n")
    bad = CliRunner().invoke(
        submit, [str(path), "--server", unreachable, "--intrinsics", str(k_file)]
    )
    assert bad.exit_code == 1
    assert "--intrinsics: K.txt holds 2 row(s)" in bad.output
