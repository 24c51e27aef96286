"""``moju serve``: Redis (embedded unless configured), N workers and the API, as one command.

Process tree::

    moju serve (this supervisor)
     |- redis-server            only without MOJU_REDIS_URL; loopback, free port,
     |                          append-only file under <data_dir>/redis
     |- python -m worker  x N   each forks a work horse per job
     '- python -m uvicorn       the API on --host:--port (default 127.0.0.1:8000)

Children run in their own sessions, so Ctrl-C in the terminal reaches only the supervisor,
which then stops them in order: the API first (no new jobs), then the workers (warm shutdown:
a running job gets ``grace`` seconds to finish, then its work horse is killed and the job is
recorded as interrupted), then Redis (which syncs its append-only file). Any child still
alive after its timeout is killed. On Linux the children also get SIGTERM if the supervisor
itself dies, and the supervisor adopts orphaned work horses (child subreaper) so that none
survives it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from service.processes import die_with_parent, stop_process, wait_or_kill
from service.redis_server import RedisServer

logger = logging.getLogger(__name__)

_PR_SET_CHILD_SUBREAPER = 36


def _become_subreaper() -> None:
    """Adopt orphaned descendants (work horses of a worker that died) on Linux."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        libc.prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)


def _adopted_children(known: set[int]) -> list[int]:
    """PIDs whose parent is this process, other than the ``known`` ones (Linux /proc)."""
    me, found = os.getpid(), []
    for entry in Path("/proc").iterdir() if Path("/proc").is_dir() else []:
        if not entry.name.isdigit() or int(entry.name) in known:
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # Fields after the parenthesised command name: state, ppid, ...
        fields = stat.rsplit(")", 1)[-1].split()
        if len(fields) > 1 and int(fields[1]) == me:
            found.append(int(entry.name))
    return found


@dataclass
class ServeOptions:
    """What ``moju serve`` was asked to run."""

    host: str = "127.0.0.1"
    port: int = 8000
    workers: int = 2
    data_dir: Path = Path("moju-data")
    redis_url: str | None = None
    grace: float = 10.0
    log_level: str = "info"
    extra_env: dict[str, str] = field(default_factory=dict)


class Supervisor:
    """Starts, watches and stops the processes of ``moju serve``."""

    def __init__(self, options: ServeOptions) -> None:
        self.options = options
        self.redis: RedisServer | None = None
        self.workers: list[subprocess.Popen] = []
        self.api: subprocess.Popen | None = None
        self.stop_requested = threading.Event()
        self.signals_received = 0

    # ---------------------------------------------------------------- starting

    def _environment(self, redis_url: str) -> dict[str, str]:
        env = dict(os.environ)
        env.update(self.options.extra_env)
        env["MOJU_REDIS_URL"] = redis_url
        env["MOJU_DATA_DIR"] = str(self.options.data_dir.resolve())
        return env

    def _spawn(self, command: list[str], env: dict[str, str]) -> subprocess.Popen:
        return subprocess.Popen(
            command, env=env, start_new_session=True, preexec_fn=die_with_parent
        )

    def start(self) -> str:
        """Start every process; return the API's base URL once it answers."""
        options = self.options
        options.data_dir.mkdir(parents=True, exist_ok=True)
        _become_subreaper()
        redis_url = options.redis_url
        if redis_url is None:
            self.redis = RedisServer(persistence_dir=options.data_dir / "redis")
            redis_url = self.redis.start()
            logger.info("embedded Redis on %s (data in %s)", redis_url, self.redis.persistence_dir)
        env = self._environment(redis_url)
        for _ in range(options.workers):
            self.workers.append(self._spawn([sys.executable, "-m", "worker"], env))
        api_command = [
            sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app",
            "--host", options.host, "--port", str(options.port),
            "--log-level", options.log_level, "--timeout-graceful-shutdown", "3",
        ]  # fmt: skip
        self.api = self._spawn(api_command, env)
        base_url = f"http://{options.host}:{options.port}"
        self._wait_for_api(base_url)
        return base_url

    def _wait_for_api(self, base_url: str, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not self.stop_requested.is_set():
            if self.api is not None and self.api.poll() is not None:
                raise RuntimeError(
                    f"the API process exited with status {self.api.returncode}; is port "
                    f"{self.options.port} already in use? (try --port)"
                )
            try:
                if httpx.get(f"{base_url}/healthz", timeout=1.0).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        if not self.stop_requested.is_set():
            raise RuntimeError(f"the API did not answer on {base_url} within {timeout:.0f} s")

    # ---------------------------------------------------------------- running

    def _on_signal(self, signum: int, frame: object) -> None:
        self.signals_received += 1
        self.stop_requested.set()

    def install_signal_handlers(self) -> None:
        """SIGINT and SIGTERM ask for an orderly stop; a second one shortens the grace."""
        signal.signal(signal.SIGINT, self._on_signal)
        signal.signal(signal.SIGTERM, self._on_signal)

    def watch(self) -> int:
        """Wait until a stop is requested (0) or a child exits on its own (1)."""
        while not self.stop_requested.wait(0.5):
            children = [("API", self.api), *(("worker", w) for w in self.workers)]
            if self.redis is not None:
                children.append(("Redis", self.redis.process))
            for name, process in children:
                if process is not None and process.poll() is not None:
                    logger.error(
                        "%s (pid %d) exited with %s", name, process.pid, process.returncode
                    )
                    return 1
        return 0

    # ---------------------------------------------------------------- stopping

    def stop(self) -> None:
        """Stop every child in order; kill whatever does not stop in time."""
        if self.api is not None:
            stop_process(self.api, timeout=10.0)
        self._stop_workers()
        known = {w.pid for w in self.workers}
        if self.api is not None:
            known.add(self.api.pid)
        if self.redis is not None and self.redis.process is not None:
            known.add(self.redis.process.pid)
        for pid in _adopted_children(known):
            logger.warning("killing leftover process %d", pid)
            try:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
            except (ProcessLookupError, ChildProcessError):
                pass
        if self.redis is not None:
            self.redis.stop()

    def _stop_workers(self) -> None:
        running = [w for w in self.workers if w.poll() is None]
        for worker in running:
            worker.send_signal(signal.SIGTERM)  # RQ: warm shutdown, finish the current job
        # RQ ignores a second signal that comes within a second of the first.
        deadline = time.monotonic() + max(self.options.grace, 1.1)
        while time.monotonic() < deadline and any(w.poll() is None for w in running):
            if self.signals_received > 1 and time.monotonic() > deadline - self.options.grace:
                break  # a second Ctrl-C: no more grace
            time.sleep(0.1)
        for worker in running:
            if worker.poll() is None:
                worker.send_signal(signal.SIGTERM)  # RQ: cold shutdown, kill the work horse
        for worker in running:
            wait_or_kill(worker, timeout=10.0)

    def run(self) -> int:
        """Start, print where the service is, watch, stop. Returns the exit status."""
        self.install_signal_handlers()
        try:
            base_url = self.start()
            if not self.stop_requested.is_set():
                print(
                    f"MoJu service on {base_url} with {self.options.workers} worker(s); "
                    "press Ctrl-C to stop",
                    flush=True,
                )
            return self.watch()
        finally:
            self.stop()
