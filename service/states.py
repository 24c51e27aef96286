"""The job states: defined here once and used by the API, the worker, the client and the CLI.

A job moves ``queued -> running -> finished | failed | cancelled``; a queued job can also go
straight to ``failed`` (its input cannot be read) or ``cancelled`` (``DELETE`` before a worker
took it). The three terminal states never change again.
"""

from __future__ import annotations

from enum import Enum


class JobStatus(str, Enum):
    """Lifecycle state of a reconstruction job."""

    QUEUED = "queued"
    RUNNING = "running"
    FINISHED = "finished"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def is_terminal(self) -> bool:
        """True for the states a job never leaves (finished, failed, cancelled)."""
        return self in TERMINAL_STATES


#: States a job never leaves.
TERMINAL_STATES = frozenset({JobStatus.FINISHED, JobStatus.FAILED, JobStatus.CANCELLED})
#: States in which a job still holds a place in the queue or a worker.
ACTIVE_STATES = frozenset({JobStatus.QUEUED, JobStatus.RUNNING})
