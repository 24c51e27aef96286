"""The solver's progress callback inside a worker: throttled reports, cancellation checks."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any
from uuid import UUID

from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError

from moju_core.result import Progress
from service.job_store import JobStore
from service.states import JobStatus

logger = logging.getLogger(__name__)

#: Least seconds between two progress writes within one stage; stage changes are always
#: written. Clients poll or stream about this often, so writing more often would be waste.
REPORT_INTERVAL = 0.5


def progress_fields(progress: Progress) -> dict[str, Any]:
    """A :class:`Progress` as JSON-ready fields (NaN, which JSON lacks, becomes None)."""

    def finite(value: float | None) -> float | None:
        return value if value is not None and math.isfinite(value) else None

    return {
        "stage": str(progress.stage),  # the Stage's value
        "iteration": progress.iteration,
        "max_iter": progress.max_iter,
        "gap": finite(progress.gap),
        "rho": finite(progress.rho),
        "fraction": min(max(progress.fraction, 0.0), 1.0),
        "elapsed": progress.elapsed,
        "eta": finite(progress.eta),
    }


class ProgressReporter:
    """``callback`` for :func:`moju_core.reconstruct` that reports to the job record.

    On every call it learns the job's status from Redis (the report itself returns it, and
    between reports one ``HGET`` does): anything but ``running`` means the job was cancelled
    or deleted, and the callback answers True so that the solver stops at this iteration.
    It also stops when ``still_ours`` says that this attempt lost the job (its lease was
    given up, see :mod:`worker.heartbeat`). A Redis that does not answer for a moment does
    not stop the solver: the report is skipped.

    Parameters
    ----------
    store : JobStore
        Where the job record lives.
    job_id : UUID
        The job being solved.
    interval : float
        Least seconds between two reports within a stage.
    clock : callable
        Monotonic clock (replaceable in tests).
    attempt : int, optional
        The attempt being run: reports of an attempt that was given up are refused.
    still_ours : callable, optional
        Returns False once the attempt no longer holds the job.
    """

    def __init__(
        self,
        store: JobStore,
        job_id: UUID,
        *,
        interval: float = REPORT_INTERVAL,
        clock: Callable[[], float] = time.monotonic,
        attempt: int | None = None,
        still_ours: Callable[[], bool] | None = None,
    ) -> None:
        self.store = store
        self.attempt = attempt
        self.still_ours = still_ours
        self.redis_errors = 0
        self.job_id = job_id
        self.interval = interval
        self.clock = clock
        self.last_report = -math.inf
        self.last_stage: str | None = None
        self.last_progress: Progress | None = None
        self.reports = 0
        self.stopped_because: JobStatus | None = None

    def __call__(self, progress: Progress) -> bool:
        """Report if due; return True when the job must stop."""
        self.last_progress = progress
        if self.still_ours is not None and not self.still_ours():
            self.stopped_because = None
            return True
        now = self.clock()
        try:
            if progress.stage != self.last_stage or now - self.last_report >= self.interval:
                status = self.store.report_progress(
                    self.job_id, progress_fields(progress), self.attempt
                )
                self.last_report = now
                self.last_stage = progress.stage
                self.reports += 1
            else:
                status = self.store.status(self.job_id)
        except (RedisConnectionError, RedisTimeoutError) as exc:
            if self.redis_errors == 0:
                logger.warning("job %s: progress not reported (%s); solving on", self.job_id, exc)
            self.redis_errors += 1
            return False
        if status is not JobStatus.RUNNING:
            self.stopped_because = status
            return True
        return False
