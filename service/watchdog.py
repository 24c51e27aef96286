"""Jobs whose worker is gone: noticed within ``MOJU_HEARTBEAT_TTL``, retried or failed.

While a job runs, its work horse renews a lease in Redis every ``MOJU_HEARTBEAT_INTERVAL``
seconds (``moju:lease:<id>``, TTL ``MOJU_HEARTBEAT_TTL``; see :mod:`worker.heartbeat`). A
worker killed with its work horse (SIGKILL, the kernel's out-of-memory killer taking the whole
container, a machine that disappears) renews nothing, and RQ itself would notice only when its
abandoned-job cleanup runs: with RQ's defaults up to ``job_monitoring_interval + 60`` seconds
for the job's registry entry to expire plus the ``maintenance_interval`` of ten minutes, and
never when no other worker is left to run that cleanup.

The API's watchdog therefore looks every ``MOJU_HEARTBEAT_INTERVAL`` seconds for running jobs
without a lease, and for jobs that a worker took from the RQ queue more than
``MOJU_HEARTBEAT_TTL`` seconds ago without starting them (it died between RQ's dequeue and the
start, a window of milliseconds); any read of such a job does the same at once. Such a job is
queued again for another worker while it has retries left (``MOJU_LOST_JOB_RETRIES``, one by
default: a job is queued at most twice); after that it is failed with an error that starts
with "worker lost". Either way the files the lost attempt may have left (a result being
written, a cached download) are deleted, so no partial result is ever visible, and the attempt
can change nothing any more: its writes carry its attempt number, which no longer matches.

A work horse killed under a worker that lives on (RQ sees its child die at once) is not this
module's business: RQ marks the job failed and :func:`service.job_store.reconcile` reports it,
quoting the signal. That is usually the out-of-memory killer, and a retry would meet it again.
"""

from __future__ import annotations

import logging
from uuid import UUID

from redis import Redis
from redis.client import Pipeline

from service import queueing
from service.job_store import JobStore
from service.schemas import JobRecord
from service.settings import Settings
from service.storage import Storage

logger = logging.getLogger(__name__)


def lost_error(settings: Settings, times_queued: int) -> str:
    """The error of a job given up after its worker was lost ``times_queued`` times."""
    times = "once" if times_queued == 1 else f"{times_queued} times"
    return (
        f"worker lost: the worker that took this job went away without finishing it (no "
        f"heartbeat for {settings.heartbeat_ttl:g} s: it was killed, ran out of memory, or its "
        f"machine or container went away); the job was queued {times} "
        f"(MOJU_LOST_JOB_RETRIES={settings.lost_job_retries}). Submit it again, with fewer "
        "points if memory is short"
    )


class Watchdog:
    """Finds running jobs without a lease and queues them again or fails them.

    Parameters
    ----------
    connection : redis.Redis
        The API's Redis client.
    store : JobStore
        The job records; its ``lost_job_handler`` is set to :meth:`handle`, so that a read
        of such a job deals with it at once.
    storage : Storage
        Job files, for deleting what a lost attempt left behind.
    settings : Settings
        ``lost_job_retries`` and ``heartbeat_ttl``, and the queue to put retries on.
    """

    def __init__(
        self, connection: Redis, store: JobStore, storage: Storage, settings: Settings
    ) -> None:
        self.connection = connection
        self.store = store
        self.storage = storage
        self.settings = settings
        store.lost_job_handler = self.handle

    def handle(self, record: JobRecord) -> str | None:
        """Deal with one job whose worker is gone; returns what was done, or None."""

        def requeue(pipeline: Pipeline, rq_id: str) -> None:
            queueing.enqueue_reconstruction(
                self.connection, self.settings, record.id, pipeline, rq_id=rq_id
            )

        times_queued = self.store.times_queued(record.id)
        outcome = self.store.give_up(
            record,
            retries=self.settings.lost_job_retries,
            requeue=requeue,
            error=lost_error(self.settings, times_queued),
        )
        if outcome is None:
            return None
        self.storage.discard_outputs(record.id)
        what = "queued again for another worker" if outcome == "requeued" else "failed"
        logger.warning(
            "job %s: its worker was lost (%s, started %d time(s)); %s",
            record.id,
            record.status.value,
            record.attempts,
            what,
        )
        return outcome

    def sweep(self) -> list[UUID]:
        """One look at every running job, and at every job a worker took from the queue
        without starting it; returns those whose worker may be gone (each was read, which
        dealt with it)."""
        lost = self.store.running_without_lease()
        lost += self.store.taken_but_not_started(self.settings.queue_name)
        for job_id in lost:
            # Reading the job runs the same checks as any read, including handle().
            if self.store.get(job_id) is None:  # deleted meanwhile, or expired
                self.store.forget_running(job_id)
        return lost
