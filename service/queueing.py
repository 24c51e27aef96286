"""The RQ side of a job: enqueueing by reference, cancelling in the queue, counting workers.

The API never imports :mod:`worker`; it names the job function by its dotted path, so the API
process does not load the solver and the two can be deployed as different images.
"""

from __future__ import annotations

import logging
from uuid import UUID

from redis import Redis
from redis.client import Pipeline
from rq import Queue, Worker
from rq.exceptions import InvalidJobOperation, NoSuchJobError
from rq.job import Job as RQJob

from service.rq_internals import RQ_WAITING
from service.settings import Settings

logger = logging.getLogger(__name__)

#: The one RQ job function; see :func:`worker.jobs.run_reconstruction`.
WORKER_FUNCTION = "worker.jobs.run_reconstruction"


def rq_job_id(job_id: UUID, times_queued: int) -> str:
    """The RQ job id of the ``times_queued``-th time a job is queued: the job id itself at
    submission, a suffixed one (``<id>-r2``, ...) each time a lost worker's job is queued
    again.

    Each is its own RQ job, so that whatever RQ records about one whose worker was given up
    (e.g. its abandoned-job cleanup, much later) never touches the one that runs now.
    """
    return str(job_id) if times_queued <= 1 else f"{job_id}-r{times_queued}"


def job_id_of_rq_job(rq_id: str) -> UUID | None:
    """Our job id from an RQ job id made by :func:`rq_job_id`; None for foreign jobs."""
    try:
        parsed = UUID(rq_id[:36])
    except ValueError:
        return None
    rest = rq_id[36:]
    if rest and not (rest.startswith("-r") and rest[2:].isdigit()):
        return None
    return parsed


def job_queue(connection: Redis, settings: Settings) -> Queue:
    """The RQ queue the API fills and the workers empty."""
    return Queue(settings.queue_name, connection=connection)


def enqueue_reconstruction(
    connection: Redis,
    settings: Settings,
    job_id: UUID,
    pipeline: Pipeline,
    *,
    rq_id: str | None = None,
) -> None:
    """Put the job on the queue as part of ``pipeline`` (the caller executes it).

    RQ's job id is our job id for the first attempt; a retry after a lost worker is another
    RQ job, ``rq_id`` (:func:`service.job_store.rq_job_id`). The time limit is
    ``MOJU_JOB_TIMEOUT``; RQ keeps its own job data as long as we keep the record
    (``MOJU_RESULT_TTL``), for operators using ``rq info``.
    """
    job_queue(connection, settings).enqueue_call(
        WORKER_FUNCTION,
        args=(str(job_id),),
        job_id=rq_id or str(job_id),
        timeout=settings.job_timeout,
        result_ttl=settings.result_ttl,
        failure_ttl=settings.result_ttl,
        description=f"moju reconstruction {job_id}",
        pipeline=pipeline,
    )


def cancel_in_queue(connection: Redis, rq_id: str) -> bool:
    """RQ's own cancel for a job no worker has taken yet; False when it is too late for that.

    ``rq_id`` is the RQ job of the job's current attempt. A job a worker already took is
    stopped by the cancelled status in its record instead, which the worker's progress
    callback reads (see :mod:`worker.progress`).
    """
    try:
        job = RQJob.fetch(rq_id, connection=connection)
        if job.get_status(refresh=False) not in RQ_WAITING:
            return False
        job.cancel()
    except (NoSuchJobError, InvalidJobOperation):
        return False
    return True


def forget(connection: Redis, job_id: UUID, times_queued: int = 1) -> None:
    """Delete RQ's data about every RQ job of a job that has ended (none is an error)."""
    for number in range(1, max(times_queued, 1) + 1):
        try:
            RQJob.fetch(rq_job_id(job_id, number), connection=connection).delete()
        except NoSuchJobError:
            pass


def count_workers(connection: Redis, settings: Settings) -> int:
    """Workers currently registered on the job queue."""
    return Worker.count(connection=connection, queue=job_queue(connection, settings))
