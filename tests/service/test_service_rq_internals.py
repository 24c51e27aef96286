"""service.rq_internals against the installed RQ: fails when a release changes what it reads.

Each test sets a job up through RQ's public API only (``Queue.enqueue``, a worker running the
job, ``Job.cancel``) and checks that the private reads agree with what RQ's public API says.
"""

from __future__ import annotations

import time
from datetime import timezone

import pytest
from redis import Redis
from rq import Queue, SimpleWorker, get_current_job
from rq.job import Job as RQJob
from rq.job import JobStatus as RQJobStatus

from service.rq_internals import (
    RQ_ALIVE,
    RQ_ENDED,
    RQ_WAITING,
    parse_rq_state,
    read_rq_state,
    rq_job_key,
    started_rq_job_ids,
)

QUEUE = "rq-internals-test"


def what_the_job_sees_of_itself() -> dict:
    """Job function: the private reads, made while RQ runs this very job."""
    job = get_current_job()
    state = parse_rq_state(read_rq_state(job.connection, job.id))
    return {
        "status": state.status,
        "started": state.started,
        "rq_started": job.started_at.replace(tzinfo=timezone.utc).timestamp(),
        "enqueued": job.enqueued_at.replace(tzinfo=timezone.utc).timestamp(),
        "running_at": time.time(),
        "in_started_registry": job.id in started_rq_job_ids(QUEUE, job.connection),
    }


@pytest.fixture
def queue(redis_client: Redis) -> Queue:
    redis_client.flushdb()
    return Queue(QUEUE, connection=redis_client)


def test_every_rq_status_is_either_alive_or_ended() -> None:
    statuses = {status.value for status in RQJobStatus}
    assert RQ_ALIVE | RQ_ENDED == statuses
    assert not RQ_ALIVE & RQ_ENDED
    assert RQ_WAITING < RQ_ALIVE


def test_a_queued_job_is_read_as_queued_and_not_started(queue: Queue, redis_client) -> None:
    job = queue.enqueue(what_the_job_sees_of_itself)
    assert redis_client.exists(rq_job_key(job.id))
    state = parse_rq_state(read_rq_state(redis_client, job.id))
    assert state.status == job.get_status() == "queued"
    assert state.started is None
    assert started_rq_job_ids(QUEUE, redis_client) == []


def test_a_running_job_is_read_as_started_at_rq_s_start_time(queue: Queue, redis_client) -> None:
    job = queue.enqueue(what_the_job_sees_of_itself)
    SimpleWorker([queue], connection=redis_client).work(burst=True)
    seen = RQJob.fetch(job.id, connection=redis_client).return_value()
    assert seen is not None, "the job did not run"
    assert seen["status"] == "started"
    # The start RQ stored when it took the job: after the enqueueing, before the job body ran.
    # RQ may refresh its in-memory start a moment later (2.6 ms on a loaded machine), so the
    # two are compared for being the same event, not to the millisecond.
    assert seen["enqueued"] <= seen["started"] <= seen["running_at"] + 1e-6
    assert seen["started"] == pytest.approx(seen["rq_started"], abs=1.0)
    assert seen["in_started_registry"]
    # After the run: ended, as RQ's public API says.
    state = parse_rq_state(read_rq_state(redis_client, job.id))
    assert state.status == job.get_status(refresh=True) == "finished"


def test_reads_work_in_a_pipeline_and_for_missing_jobs(queue: Queue, redis_client) -> None:
    job = queue.enqueue(what_the_job_sees_of_itself)
    job.cancel()
    pipe = redis_client.pipeline(transaction=False)
    read_rq_state(pipe, job.id)
    read_rq_state(pipe, "no-such-job")
    cancelled, missing = (parse_rq_state(raw) for raw in pipe.execute())
    assert cancelled.status == job.get_status(refresh=True) == "canceled"
    assert missing.status is None and missing.started is None
