"""The heartbeat of a running job: a thread in the work horse that renews the job's lease.

The lease (``moju:lease:<id>``) tells the API's watchdog (:mod:`service.watchdog`) that the
job's worker is alive. The thread renews it every ``MOJU_HEARTBEAT_INTERVAL`` seconds for
``MOJU_HEARTBEAT_TTL`` seconds. It runs in the work horse itself, the process doing the work:
a worker whose work horse goes on after the worker died keeps the job, and a work horse that
dies takes its heartbeat with it.

When the renewal is refused, the job no longer runs this attempt (it ended, was cancelled,
or the watchdog gave the attempt up after missed heartbeats): :attr:`Heartbeat.lost` is set,
and the progress callback stops the solver at its next call.
"""

from __future__ import annotations

import logging
import threading
from types import TracebackType
from uuid import UUID

from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError

from service.job_store import JobStore

logger = logging.getLogger(__name__)


class Heartbeat:
    """Renews a running attempt's lease from a daemon thread while the ``with`` block runs.

    Parameters
    ----------
    store : JobStore
        Where the job's record and lease live.
    job_id : UUID
        The job.
    attempt : int
        The attempt this work horse runs (returned by :meth:`JobStore.start`).
    interval : float
        Seconds between two renewals.
    ttl : float
        Lifetime given to the lease at each renewal.
    """

    def __init__(
        self, store: JobStore, job_id: UUID, attempt: int, *, interval: float, ttl: float
    ) -> None:
        self.store = store
        self.job_id = job_id
        self.attempt = attempt
        self.interval = interval
        self.ttl = ttl
        self.lost = threading.Event()
        self.beats = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"heartbeat-{job_id}", daemon=True)

    def _run(self) -> None:
        unreachable = False
        while not self._stop.wait(self.interval):
            try:
                alive = self.store.heartbeat(self.job_id, self.attempt, lease_seconds=self.ttl)
            except (RedisConnectionError, RedisTimeoutError) as exc:
                # Keep solving through a short Redis outage; the lease is renewed (or made
                # again) once Redis answers, unless the outage outlasted it.
                if not unreachable:
                    logger.warning("job %s: heartbeat failed (%s); retrying", self.job_id, exc)
                unreachable = True
                continue
            unreachable = False
            self.beats += 1
            if not alive:
                logger.warning(
                    "job %s: attempt %d no longer holds the job (ended, cancelled, or given up "
                    "after missed heartbeats); stopping it",
                    self.job_id,
                    self.attempt,
                )
                self.lost.set()
                return

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._stop.set()
        self._thread.join(timeout=max(self.interval, 1.0) + 5.0)
