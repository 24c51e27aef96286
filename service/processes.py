"""Small helpers for the child processes of ``moju serve`` and of the test suite."""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import socket
import subprocess
import sys
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
