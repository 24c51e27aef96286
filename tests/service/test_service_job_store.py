"""Job records in Redis: the state machine, retention, reconciliation with RQ, the sweep."""

from __future__ import annotations

import os
import time
from datetime import datetime, timezone
from pathlib import Path
from uuid import UUID, uuid4

import pytest
from redis import Redis

from moju_core.params import SolverParams
from service.job_store import INDEX_KEY, JobStore, reconcile, record_key
from service.retention import sweep
from service.schemas import InputSummary, JobRecord
from service.states import JobStatus
from service.storage import LocalStorage

RETENTION = 3600


@pytest.fixture
def store(redis_client: Redis) -> JobStore:
    return JobStore(redis_client, retention_seconds=RETENTION)


def new_record(created: float | None = None) -> JobRecord:
    created_at = datetime.fromtimestamp(created or time.time(), tz=timezone.utc)
    return JobRecord(
        id=uuid4(),
        status=JobStatus.QUEUED,
        created_at=created_at,
        parameters=SolverParams(max_iter=12),
        input=InputSummary(
            frames=3,
            points=10,
            format="json",
            size_bytes=100,
            has_rotations=False,
            has_ground_truth=False,
            has_faces=False,
            has_colors=False,
        ),
    )


def add(store: JobStore, record: JobRecord) -> UUID:
    with store.connection.pipeline() as pipe:
        store.add(record, pipe)
        pipe.execute()
    return record.id


def test_record_round_trips(store: JobStore) -> None:
    record = new_record()
    add(store, record)
    read = store.get(record.id, reconcile_with_rq=False)
    assert read == record
    # Only what the user set is stored, so the worker sees the same "explicitly set" fields.
    assert read.parameters.model_fields_set == {"max_iter"}


def test_state_machine_refuses_illegal_moves(store: JobStore) -> None:
    job_id = add(store, new_record())
    assert not store.finish(job_id, {}, {})  # queued -> finished: no
    assert store.start(job_id)
    assert not store.start(job_id)  # running -> running: no
    assert store.connection.ttl(record_key(job_id)) == -1  # active: kept
    assert store.cancel(job_id)
    assert not store.finish(job_id, {}, {})  # cancelled is terminal
    assert not store.fail(job_id, "late")
    assert store.status(job_id) is JobStatus.CANCELLED
    assert 0 < store.connection.ttl(record_key(job_id)) <= RETENTION
    assert not store.start(uuid4())  # unknown job


def test_progress_only_while_running(store: JobStore) -> None:
    job_id = add(store, new_record())
    assert store.report_progress(job_id, {"stage": "x"}) is JobStatus.QUEUED
    assert store.connection.hget(record_key(job_id), "progress") is None
    store.start(job_id)
    assert store.report_progress(job_id, {"stage": "x"}) is JobStatus.RUNNING
    assert store.connection.hget(record_key(job_id), "progress") == b'{"stage": "x"}'
    store.remove(job_id)
    assert store.report_progress(job_id, {"stage": "y"}) is None
    assert store.connection.exists(record_key(job_id)) == 0


@pytest.mark.parametrize(
    ("status", "rq_status", "expected"),
    [
        (JobStatus.RUNNING, "started", None),
        (JobStatus.QUEUED, "queued", None),
        (JobStatus.FINISHED, None, None),
        (JobStatus.RUNNING, None, "the job queue lost this job"),
        (JobStatus.RUNNING, "failed", "the worker running this job stopped"),
        (JobStatus.RUNNING, "stopped", "an operator stopped this job"),
        (JobStatus.QUEUED, "canceled", "the job was cancelled in the queue"),
    ],
)
def test_reconcile(status: JobStatus, rq_status: str | None, expected: str | None) -> None:
    record = new_record().model_copy(update={"status": status})
    reason = reconcile(record, rq_status, None)
    assert reason == expected if expected is None else reason.startswith(expected)


def test_reconcile_quotes_the_last_line_of_the_worker_report() -> None:
    record = new_record().model_copy(update={"status": JobStatus.RUNNING})
    report = "Traceback...\nWork-horse terminated unexpectedly; waitpid returned 9 (signal 9); "
    reason = reconcile(record, "failed", report)
    assert "(worker report: Work-horse terminated unexpectedly" in reason


def test_job_cancelled_with_rq_is_cancelled_on_read(store: JobStore, redis_client) -> None:
    from rq import Queue

    job_id = add(store, new_record())
    Queue("moju", connection=redis_client).enqueue_call(
        "worker.jobs.run_reconstruction", args=(str(job_id),), job_id=str(job_id)
    ).cancel()
    record = store.get(job_id)
    assert record.status is JobStatus.CANCELLED
    assert record.error == "the job was cancelled in the queue by an operator (rq cancel)"


def test_job_lost_by_the_queue_is_failed_on_read(store: JobStore) -> None:
    job_id = add(store, new_record())  # a record without any RQ job
    record = store.get(job_id)
    assert record.status is JobStatus.FAILED
    assert record.error.startswith("the job queue lost this job")
    assert store.status(job_id) is JobStatus.FAILED  # written back once


def test_page_newest_first_and_prunes_expired(store: JobStore) -> None:
    now = time.time()
    ids = [add(store, new_record(now + i)) for i in range(4)]
    store.connection.delete(record_key(ids[2]))
    records, total = store.page(limit=2, offset=0)
    assert [r.id for r in records] == [ids[3]]  # ids[2] expired and is skipped
    assert total == 3
    assert store.connection.zcard(INDEX_KEY) == 3
    records, total = store.page(limit=10, offset=0)
    assert [r.id for r in records] == [ids[3], ids[1], ids[0]]


def test_sweep_deletes_files_of_expired_jobs_only(store: JobStore, tmp_path: Path) -> None:
    storage = LocalStorage(tmp_path)
    live, expired, young = (add(store, new_record()) for _ in range(3))
    for job_id in (live, expired, young):
        storage.create(job_id)
    old = time.time() - 7200
    for job_id in (live, expired):
        os.utime(tmp_path / "jobs" / str(job_id), (old, old))
    store.connection.delete(record_key(expired), record_key(young))
    (tmp_path / "jobs" / "not-a-job").mkdir()

    assert sweep(store, storage, grace_seconds=600) == 1

    remaining = {path.name for path in (tmp_path / "jobs").iterdir()}
    assert remaining == {str(live), str(young), "not-a-job"}
    assert store.connection.zcard(INDEX_KEY) == 1  # index entries of both gone records pruned


def test_another_owners_job_is_refused_before_it_is_decoded(
    store: JobStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Refusing another key's job costs what an unknown id costs: no record is decoded."""
    import service.job_store as job_store

    job_id = add(store, new_record().owned_by("key-aaaaaaaaaaaaaaaa"))
    decoded = []
    real_decode = job_store._decode
    monkeypatch.setattr(job_store, "_decode", lambda *a: decoded.append(a) or real_decode(*a))
    assert store.get(job_id, owner="key-bbbbbbbbbbbbbbbb") is None
    assert store.get(job_id, owner="") is None
    assert decoded == []
    assert store.get(job_id, owner="key-aaaaaaaaaaaaaaaa") is not None
    assert decoded  # its own owner gets it
