"""Small helpers for the child processes of ``moju serve`` and of the test suite."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

# From <linux/prctl.h>.
_PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """``preexec_fn`` that makes a child get SIGTERM when its parent dies (Linux only).

    Without it, a supervisor killed with SIGKILL (which it cannot handle) would leave its
    Redis and workers running as orphans. Elsewhere this does nothing.
    """
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago (the caller must cope with a lost race)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def wait_or_kill(process: subprocess.Popen, *, timeout: float) -> int:
    """Wait up to ``timeout`` seconds for ``process`` to exit, then SIGKILL it."""
    try:
        return process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        return process.wait()


def stop_process(process: subprocess.Popen, *, timeout: float, sig: int = signal.SIGTERM) -> int:
    """Send ``sig``, wait up to ``timeout`` seconds, then SIGKILL; return the exit status."""
    if process.poll() is None:
        try:
            os.kill(process.pid, sig)
        except ProcessLookupError:
            pass
    return wait_or_kill(process, timeout=timeout)


#: Seconds between two signals to the same RQ worker. RQ ignores a shutdown signal that comes
#: within a second of the one that began its warm shutdown (``request_force_stop``, which
#: is meant for the duplicate signals of a worker pool), timed from when the worker *handled*
#: that one: a busy or niced worker that handles it late ignores a second signal sent a
#: second after it was sent.
RQ_SIGNAL_SPACING = 1.25


def signal_until_exit(
    processes: Sequence[subprocess.Popen], *, timeout: float, sig: int = signal.SIGTERM
) -> None:
    """Send ``sig`` to each process that runs, again every :data:`RQ_SIGNAL_SPACING` seconds
    while it still runs, for up to ``timeout`` seconds; then SIGKILL the ones left and reap
    them all.

    Used for an RQ worker's cold shutdown, which a single signal may not start (see
    :data:`RQ_SIGNAL_SPACING`); the worker ignores the repeats once it is going down
    (:meth:`worker.runner.MojuWorker.request_force_stop`).
    """
    deadline = time.monotonic() + timeout
    while True:
        running = [p for p in processes if p.poll() is None]
        if not running or time.monotonic() >= deadline:
            break
        for process in running:
            try:
                os.kill(process.pid, sig)
            except ProcessLookupError:
                pass
        resend = min(time.monotonic() + RQ_SIGNAL_SPACING, deadline)
        while time.monotonic() < resend and any(p.poll() is None for p in running):
            time.sleep(0.05)
    for process in processes:
        wait_or_kill(process, timeout=0.0)


def _parents() -> dict[int, int]:
    """Parent PID of every process, from Linux's /proc."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[-1].split()
            except OSError:
                continue  # gone meanwhile
            parents[int(entry.name)] = int(fields[1])
    return parents


def children_of(pid: int) -> list[int]:
    """PIDs whose parent is ``pid`` (e.g. an RQ worker's work horse); used by the fault tests
    and the soak benchmark to kill a job mid-solve."""
    return [child for child, parent in _parents().items() if parent == pid]


def descendants(pid: int) -> set[int]:
    """Every process below ``pid``: children, their children, and so on."""
    parents = _parents()
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier}
        found |= frontier
    return found
