"""``moju serve``: Redis (embedded unless configured), N workers and the API, as one command.

Process tree::

    moju serve (this supervisor)
     |- redis-server            only without MOJU_REDIS_URL; loopback, a free port kept
     |                          across restarts, append-only file under <data_dir>/redis
     |- python -m worker  x N   each forks a work horse per job
     '- python -m service.uvicorn_server   the API under uvicorn on --host:--port (default
                                           127.0.0.1:8000), with the slow-client limits

A child that dies is started again after a pause that doubles with each quick death
(:class:`RestartPolicy`); the supervisor logs each death and restart and tells the API what is
down (:mod:`service.serve_status`, shown by ``/readyz``). The work horse a dead worker left
behind is killed before the worker is replaced: its job is then found without a lease and
queued again or failed by the API's watchdog, as for any lost worker. A child that keeps dying
(a crash loop) makes the supervisor give up with a message naming it, and only then does the
whole service stop.

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
from redis import Redis
from redis.exceptions import RedisError

from service.processes import (
    RQ_SIGNAL_SPACING,
    die_with_parent,
    signal_until_exit,
    stop_process,
)
from service.redis_server import RedisServer
from service.serve_status import publish_down

logger = logging.getLogger(__name__)

_PR_SET_CHILD_SUBREAPER = 36
#: Seconds between two looks at the children.
POLL_SECONDS = 0.25


def _become_subreaper() -> None:
    """Adopt orphaned descendants (work horses of a worker that died) on Linux."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        libc.prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)


def _session_members(sessions: set[int]) -> list[int]:
    """PIDs of live processes in any of the given sessions (Linux /proc).

    Every child of the supervisor leads its own session, and a work horse stays in its
    worker's session (RQ gives it only its own process group), so the horses a worker left
    behind are the members of that worker's session.
    """
    found = []
    for entry in Path("/proc").iterdir() if Path("/proc").is_dir() else []:
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # Fields after the parenthesised command name: state, ppid, pgrp, session, ...
        fields = stat.rsplit(")", 1)[-1].split()
        if len(fields) > 3 and fields[0] != "Z" and int(fields[3]) in sessions:
            found.append(int(entry.name))
    return found


def _kill_and_reap(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        return
    try:
        os.waitpid(pid, 0)  # ours once adopted (subreaper)
    except ChildProcessError:
        pass


def describe_exit(status: int | None) -> str:
    """``exit status 1`` or ``signal SIGKILL`` for a ``Popen.returncode``."""
    if status is None:
        return "no exit status"
    if status < 0:
        try:
            return f"signal {signal.Signals(-status).name}"
        except ValueError:
            return f"signal {-status}"
    return f"exit status {status}"


@dataclass(frozen=True)
class RestartPolicy:
    """When a child that died is started again, and when the supervisor gives up.

    The pause before a restart is ``first_delay`` seconds and doubles with each death that
    ends a short life (under ``stable_after`` seconds), up to ``max_delay``; a child that ran
    for ``stable_after`` seconds starts over at ``first_delay``. A child that dies more than
    ``max_restarts`` times within ``window`` seconds is in a crash loop: the supervisor gives
    up and stops the service.
    """

    first_delay: float = 0.5
    max_delay: float = 10.0
    stable_after: float = 30.0
    max_restarts: int = 5
    window: float = 120.0

    def delay(self, child: Child, now: float) -> float | None:
        """Seconds to wait before restarting ``child``, which just died; None: give up."""
        child.deaths = [t for t in child.deaths if now - t <= self.window] + [now]
        if len(child.deaths) > self.max_restarts:
            return None
        lived = now - child.started_at
        child.quick_deaths = child.quick_deaths + 1 if lived < self.stable_after else 1
        return min(self.max_delay, self.first_delay * 2 ** (child.quick_deaths - 1))


@dataclass
class Child:
    """One supervised process and the history of its deaths."""

    name: str
    kind: str  # "redis", "worker" or "api"
    process: subprocess.Popen | None = None
    started_at: float = 0.0
    deaths: list[float] = field(default_factory=list)
    quick_deaths: int = 0
    restart_at: float | None = None
    last_exit: str = ""

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid


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
    queue_name: str = "moju"
    restart: RestartPolicy = field(default_factory=RestartPolicy)


class Supervisor:
    """Starts, watches, restarts and stops the processes of ``moju serve``."""

    def __init__(self, options: ServeOptions) -> None:
        self.options = options
        self.redis: RedisServer | None = None
        self.redis_child: Child | None = None
        self.worker_children: list[Child] = []
        self.api_child = Child("the API", "api")
        self.stop_requested = threading.Event()
        self.signals_received = 0
        self.gave_up: str | None = None
        self._env: dict[str, str] = {}
        self._status: Redis | None = None
        self._published: list[str] | None = None

    @property
    def workers(self) -> list[subprocess.Popen]:
        """The current worker processes."""
        return [c.process for c in self.worker_children if c.process is not None]

    @property
    def api(self) -> subprocess.Popen | None:
        """The current API process."""
        return self.api_child.process

    def children(self) -> list[Child]:
        """Every supervised child, in the order they are started."""
        first = [self.redis_child] if self.redis_child is not None else []
        return [*first, *self.worker_children, self.api_child]

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

    def worker_command(self) -> list[str]:
        """The command line of one worker."""
        return [sys.executable, "-m", "worker"]

    def api_command(self) -> list[str]:
        """The command line of the API."""
        options = self.options
        return [
            sys.executable, "-m", "service.uvicorn_server",
            "--host", options.host, "--port", str(options.port),
            "--log-level", options.log_level, "--timeout-graceful-shutdown", "3",
        ]  # fmt: skip

    def _launch(self, child: Child) -> None:
        """Start (or start again) one child."""
        if child.kind == "redis":
            assert self.redis is not None
            self.redis.start()  # same port as before: clients reconnect to the same URL
            child.process = self.redis.process
        elif child.kind == "worker":
            child.process = self._spawn(self.worker_command(), self._env)
        else:
            child.process = self._spawn(self.api_command(), self._env)
        assert child.process is not None
        child.started_at = time.monotonic()
        child.restart_at = None

    def start(self) -> str:
        """Start every process; return the API's base URL once it answers."""
        options = self.options
        options.data_dir.mkdir(parents=True, exist_ok=True)
        _become_subreaper()
        redis_url = options.redis_url
        if redis_url is None:
            self.redis = RedisServer(persistence_dir=options.data_dir / "redis")
            self.redis_child = Child("Redis", "redis")
            self._launch(self.redis_child)
            self.redis.fixed_port = self.redis.port
            redis_url = self.redis.url
            logger.info("embedded Redis on %s (data in %s)", redis_url, self.redis.persistence_dir)
        self._env = self._environment(redis_url)
        self._status = Redis.from_url(redis_url, socket_connect_timeout=0.5, socket_timeout=1)
        for number in range(1, options.workers + 1):
            child = Child(f"worker {number}", "worker")
            self.worker_children.append(child)
            self._launch(child)
        self._launch(self.api_child)
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

    def _kill_leftovers_of(self, child: Child) -> None:
        """Kill what a dead child left running in its session (a worker's work horse).

        Done as soon as the death is seen: a session id is the pid of a process that is
        gone, and only until the system gives that pid to another process does it name
        the dead child's session.
        """
        if child.pid is None:
            return
        for pid in _session_members({child.pid}):
            logger.warning("killing process %d left behind by %s", pid, child.name)
            _kill_and_reap(pid)

    def _on_death(self, child: Child, now: float) -> bool:
        """Note a child's death and plan its restart; False when it is in a crash loop."""
        assert child.process is not None
        child.last_exit = f"exited with {describe_exit(child.process.returncode)}"
        self._kill_leftovers_of(child)
        delay = self.options.restart.delay(child, now)
        if delay is None:
            policy = self.options.restart
            self.gave_up = (
                f"giving up: {child.name} died {len(child.deaths)} times within "
                f"{policy.window:.0f} s (last {child.last_exit}); stopping the service. "
                "Its own messages above say why it failed"
            )
            logger.error("%s", self.gave_up)
            return False
        child.restart_at = now + delay
        logger.warning(
            "%s (pid %d) %s; restarting it in %.1f s", child.name, child.pid, child.last_exit, delay
        )
        return True

    def _restart(self, child: Child) -> None:
        try:
            self._launch(child)
        except RuntimeError as exc:  # Redis could not start (e.g. its port was taken)
            logger.error("%s did not start again: %s", child.name, exc)
            child.process = None
            child.restart_at = time.monotonic() + self.options.restart.max_delay
            return
        logger.info("%s started again (pid %d)", child.name, child.pid)

    def _publish(self, now: float) -> None:
        """Tell the API (``/readyz``) which children are down, while any is."""
        down = [
            f"{c.name} {c.last_exit}; restarting in {max(0.0, (c.restart_at or now) - now):.1f} s"
            for c in self.children()
            if c.restart_at is not None and c.kind != "api"
        ]
        if self._status is None or (not down and not self._published):
            return
        try:
            publish_down(self._status, self.options.queue_name, down)
            self._published = down
        except RedisError:
            pass  # Redis itself is down: the API says so on its own

    def check_children(self) -> bool:
        """One look at every child: note deaths, restart what is due. False: give up."""
        now = time.monotonic()
        for child in self.children():
            if child.restart_at is None:
                if child.process is not None and child.process.poll() is not None:
                    if not self._on_death(child, now):
                        return False
            elif now >= child.restart_at:
                self._restart(child)
        self._publish(now)
        return True

    def watch(self) -> int:
        """Keep every child running until a stop is requested (0) or one crash-loops (1)."""
        while not self.stop_requested.wait(POLL_SECONDS):
            if not self.check_children():
                return 1
        return 0

    # ---------------------------------------------------------------- stopping

    def stop(self) -> None:
        """Stop every child in order; kill whatever does not stop in time."""
        if self.api is not None:
            stop_process(self.api, timeout=10.0)
        self._stop_workers()
        # The API and the workers have exited: whatever is left in their sessions (a work
        # horse whose worker did not stop) is killed; Redis stops last.
        for child in [*self.worker_children, self.api_child]:
            if child.restart_at is None:  # a child in its pause was swept when it died
                self._kill_leftovers_of(child)
        if self._status is not None:
            try:
                publish_down(self._status, self.options.queue_name, [])
            except RedisError:
                pass
            self._status.close()
        if self.redis is not None:
            self.redis.stop()

    def _stop_workers(self) -> None:
        running = [w for w in self.workers if w.poll() is None]
        for worker in running:
            worker.send_signal(signal.SIGTERM)  # RQ: warm shutdown, finish the current job
        # RQ ignores a second signal that comes within a second of the first.
        deadline = time.monotonic() + max(self.options.grace, RQ_SIGNAL_SPACING)
        while time.monotonic() < deadline and any(w.poll() is None for w in running):
            if self.signals_received > 1 and time.monotonic() > deadline - self.options.grace:
                break  # a second Ctrl-C: no more grace
            time.sleep(0.1)
        # RQ's cold shutdown: the work horse killed, the job recorded as interrupted. Sent
        # again until the worker exits: one that handled the warm signal late ignores it.
        signal_until_exit(running, timeout=10.0)

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
