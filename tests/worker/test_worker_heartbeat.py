"""Leases, heartbeats and attempts on a real Redis: what keeps a lost worker from doing harm."""

from __future__ import annotations

import threading
import time
from datetime import datetime, timedelta, timezone
from uuid import UUID

import pytest
from redis import Redis
from rq import Queue
from rq.registry import StartedJobRegistry
from rq.utils import utcformat

from moju_core.params import SolverParams
from service.job_store import RUNNING_KEY, JobStore, active_key, lease_key, record_key
from service.queueing import enqueue_reconstruction, rq_job_id
from service.rq_internals import rq_job_key
from service.settings import Settings
from service.states import JobStatus
from service.storage import INPUT_NAME, LocalStorage
from service.watchdog import Watchdog
from worker.heartbeat import Heartbeat
from worker.jobs import execute

LONG = SolverParams(max_iter=10_000, tol=0.0, rho_growth=1.0005, rho_max=1e12)


@pytest.fixture
def add_job(store: JobStore, settings: Settings, add_job):  # noqa: F811 - wraps conftest's
    """conftest's add_job, plus the RQ job the API would have queued with the record."""

    def add(*args, **kwargs) -> UUID:
        job_id = add_job(*args, **kwargs)
        with store.connection.pipeline() as pipe:
            enqueue_reconstruction(store.connection, settings, job_id, pipe)
            pipe.execute()
        return job_id

    return add


def _expire_lease(store: JobStore, job_id: UUID) -> None:
    store.connection.delete(lease_key(job_id))


def test_settings_refuse_a_ttl_shorter_than_two_beats() -> None:
    with pytest.raises(ValueError, match="at least twice heartbeat_interval"):
        Settings(heartbeat_interval=5, heartbeat_ttl=9)
    assert Settings(heartbeat_interval=5, heartbeat_ttl=10).heartbeat_ttl == 10


def test_start_takes_a_lease_that_the_heartbeat_keeps(store: JobStore, add_job, face_W) -> None:
    job_id = add_job(face_W)
    attempt = store.start(job_id, lease_seconds=0.6)
    assert attempt == 1
    assert store.connection.zscore(RUNNING_KEY, str(job_id)) is not None
    with Heartbeat(store, job_id, attempt, interval=0.1, ttl=0.6) as heartbeat:
        time.sleep(1.5)  # more than twice the lease: alive only thanks to the beats
        assert store.connection.exists(lease_key(job_id))
        assert heartbeat.beats >= 5 and not heartbeat.lost.is_set()
    time.sleep(0.8)  # no more beats: the lease runs out
    assert not store.connection.exists(lease_key(job_id))
    assert store.running_without_lease() == [job_id]


def test_ending_a_job_drops_its_lease_and_slot(store: JobStore, add_job, face_W) -> None:
    job_id = add_job(face_W)
    store.connection.zadd(active_key(""), {str(job_id): time.time()})
    attempt = store.start(job_id, lease_seconds=30)
    assert store.finish(job_id, {}, {}, attempt)
    assert not store.connection.exists(lease_key(job_id))
    assert store.connection.zscore(RUNNING_KEY, str(job_id)) is None
    assert store.active_count("") == 0


def test_an_attempt_given_up_can_change_nothing(
    store: JobStore, storage: LocalStorage, settings: Settings, add_job, face_W, redis_url: str
) -> None:
    job_id = add_job(face_W)
    watchdog = Watchdog(Redis.from_url(redis_url), store, storage, settings)
    first = store.start(job_id, lease_seconds=30)
    _expire_lease(store, job_id)  # as if its worker had died 30 s ago

    record = store.get(job_id)  # any read notices, and the watchdog queues it again
    assert record.status is JobStatus.QUEUED and record.attempts == 1
    assert store.rq_job_of(job_id) == rq_job_id(job_id, 2) == f"{job_id}-r2"
    assert store.connection.lrange(f"rq:queue:{settings.queue_name}", 0, -1) == [
        str(job_id).encode(),  # the first attempt's entry (no worker took it in this test)
        f"{job_id}-r2".encode(),
    ]
    assert watchdog.sweep() == []  # nothing left to do

    second = store.start(job_id, lease_seconds=30)
    assert second == 2
    # The first attempt's worker turns out to be alive after all: it is ignored.
    assert not store.heartbeat(job_id, first, lease_seconds=30)
    assert store.report_progress(job_id, {"stage": "late"}, first) is None
    assert not store.finish(job_id, {}, {}, first)
    assert not store.fail(job_id, "late failure", first)
    assert store.status(job_id) is JobStatus.RUNNING
    # The second attempt holds the job.
    assert store.heartbeat(job_id, second, lease_seconds=30)
    assert store.report_progress(job_id, {"stage": "x"}, second) is JobStatus.RUNNING
    assert store.finish(job_id, {}, {}, second)


def test_lost_again_without_retries_left_fails_and_discards_outputs(
    store: JobStore, storage: LocalStorage, settings: Settings, add_job, face_W, redis_url: str
) -> None:
    job_id = add_job(face_W)
    store.connection.zadd(active_key(""), {str(job_id): time.time()})
    watchdog = Watchdog(Redis.from_url(redis_url), store, storage, settings)
    directory = settings.data_dir / "jobs" / str(job_id)
    for attempt in (1, 2):
        assert store.start(job_id, lease_seconds=30) == attempt
        # What a work horse killed while writing its result leaves behind.
        (directory / f".result.h5.{attempt:012x}.tmp").write_bytes(b"half a file")
        _expire_lease(store, job_id)
        assert watchdog.sweep() == [job_id]
        assert sorted(p.name for p in directory.iterdir()) == [INPUT_NAME]
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.FAILED and record.attempts == 2
    assert record.error.startswith("worker lost: the worker that took this job went away")
    assert "queued 2 times (MOJU_LOST_JOB_RETRIES=1)" in record.error
    assert 0 < store.connection.ttl(record_key(job_id)) <= settings.result_ttl
    assert store.active_count("") == 0
    assert store.connection.zcard(RUNNING_KEY) == 0


def test_no_retry_when_retries_are_off(
    store: JobStore, storage: LocalStorage, settings: Settings, add_job, face_W, redis_url: str
) -> None:
    no_retry = settings.model_copy(update={"lost_job_retries": 0})
    job_id = add_job(face_W)
    Watchdog(Redis.from_url(redis_url), store, storage, no_retry)
    store.start(job_id, lease_seconds=30)
    _expire_lease(store, job_id)
    record = store.get(job_id)
    assert record.status is JobStatus.FAILED
    assert "queued once (MOJU_LOST_JOB_RETRIES=0)" in record.error


def test_a_late_heartbeat_keeps_the_job(
    store: JobStore, storage: LocalStorage, settings: Settings, add_job, face_W, redis_url: str
) -> None:
    """A heartbeat that comes after the lease ran out, before the watchdog looked, counts."""
    job_id = add_job(face_W)
    watchdog = Watchdog(Redis.from_url(redis_url), store, storage, settings)
    attempt = store.start(job_id, lease_seconds=30)
    _expire_lease(store, job_id)
    assert store.heartbeat(job_id, attempt, lease_seconds=30)  # makes the lease again
    assert watchdog.sweep() == []
    assert store.get(job_id).status is JobStatus.RUNNING


def test_running_attempt_stops_when_given_up(
    store: JobStore, storage: LocalStorage, settings: Settings, add_job, long_W, redis_url: str
) -> None:
    """The work horse of an attempt the watchdog gave up stops solving and records nothing."""
    fast = settings.model_copy(update={"heartbeat_interval": 0.1, "heartbeat_ttl": 0.5})
    job_id = add_job(long_W, LONG)
    watchdog = Watchdog(Redis.from_url(redis_url), store, storage, fast)
    outcome: dict = {}
    runner = threading.Thread(
        target=lambda: outcome.update(execute(job_id, store, storage, fast)), daemon=True
    )
    runner.start()
    deadline = time.monotonic() + 30
    while (store.get(job_id, reconcile_with_rq=False).progress or {}) == {}:
        assert time.monotonic() < deadline, "the job never reported progress"
        time.sleep(0.02)
    # Take the job away as the watchdog would after missed heartbeats (the beats of the
    # running thread may renew the lease in between: try until the watchdog wins).
    record = store.get(job_id, reconcile_with_rq=False)
    while watchdog.handle(record) is None:
        _expire_lease(store, job_id)
        assert time.monotonic() < deadline, "the watchdog never took the job"
    given_up = time.monotonic()
    runner.join(timeout=10)
    assert not runner.is_alive()
    assert time.monotonic() - given_up < 5.0  # next beat, with slack for load
    assert outcome == {"status": "superseded"}
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.QUEUED and record.progress is None
    assert not storage.has_result(job_id)


def test_attempt_that_sees_its_job_queued_again_is_superseded_not_cancelled(
    store: JobStore, storage: LocalStorage, settings: Settings, add_job, long_W
) -> None:
    """The solver may read the status ``queued`` (given up by the watchdog) before its own
    heartbeat learns that the lease is gone: that is not a user's cancel."""
    job_id = add_job(long_W, LONG)
    outcome: dict = {}
    runner = threading.Thread(
        target=lambda: outcome.update(execute(job_id, store, storage, settings)), daemon=True
    )
    runner.start()
    deadline = time.monotonic() + 30
    while (store.get(job_id, reconcile_with_rq=False).progress or {}) == {}:
        assert time.monotonic() < deadline, "the job never reported progress"
        time.sleep(0.02)
    # The lease is still held (default heartbeat settings): only the status tells.
    store.connection.hset(record_key(job_id), "status", JobStatus.QUEUED.value)
    runner.join(timeout=10)
    assert not runner.is_alive()
    assert outcome == {"status": "superseded"}
    assert store.status(job_id) is JobStatus.QUEUED
    assert not storage.has_result(job_id)


def _taken_by_a_worker_that_died(store: JobStore, settings: Settings, job_id: UUID, ago: float):
    """What a worker killed between RQ's dequeue and the start leaves: RQ says 'started'
    (since ``ago`` seconds), the record still says 'queued'."""
    connection = store.connection
    queue = Queue(settings.queue_name, connection=connection)
    job, _ = queue.dequeue_any([queue], None, connection=connection)
    started = datetime.now(timezone.utc) - timedelta(seconds=ago)
    connection.hset(
        rq_job_key(job.id), mapping={"status": "started", "started_at": utcformat(started)}
    )
    registry = StartedJobRegistry(settings.queue_name, connection=connection)
    connection.zadd(registry.key, {f"{job.id}:deadbeef": time.time() + 60})
    return job.id


def test_a_job_taken_but_never_started_is_queued_again(
    store: JobStore, storage: LocalStorage, settings: Settings, add_job, face_W, redis_url: str
) -> None:
    job_id = add_job(face_W)
    store.lease_seconds = 30
    watchdog = Watchdog(Redis.from_url(redis_url), store, storage, settings)
    _taken_by_a_worker_that_died(store, settings, job_id, ago=5)
    assert store.get(job_id).status is JobStatus.QUEUED  # 5 s: maybe still starting
    assert watchdog.sweep() == [job_id]  # a candidate, judged alive for now
    assert store.rq_job_of(job_id) == str(job_id)

    connection = store.connection
    old = utcformat(datetime.now(timezone.utc) - timedelta(seconds=31))
    connection.hset(rq_job_key(str(job_id)), "started_at", old)
    assert watchdog.sweep() == [job_id]
    record = store.get(job_id, reconcile_with_rq=False)
    assert record.status is JobStatus.QUEUED and record.attempts == 0
    assert store.rq_job_of(job_id) == f"{job_id}-r2" and store.times_queued(job_id) == 2
    assert connection.lrange(f"rq:queue:{settings.queue_name}", 0, -1) == [f"{job_id}-r2".encode()]
    # The next worker starts it as its first attempt.
    assert store.start(job_id, lease_seconds=30) == 1
