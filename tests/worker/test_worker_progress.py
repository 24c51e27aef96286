"""The worker's progress callback: throttled reports and cancellation, on a real Redis."""

from __future__ import annotations

import math

from moju_core.result import Progress
from service.job_store import record_key
from service.states import JobStatus
from worker.progress import ProgressReporter, progress_fields


class FakeClock:
    """A clock the test advances by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def progress(stage: str, iteration: int = 0, gap: float = math.nan) -> Progress:
    return Progress(
        stage=stage,
        iteration=iteration,
        max_iter=300,
        gap=gap,
        rho=0.01,
        fraction=0.05,
        elapsed=1.0,
        eta=None,
    )


def stored_progress(store, job_id) -> dict | None:
    record = store.get(job_id, reconcile_with_rq=False)
    return None if record.progress is None else record.progress.model_dump()


def test_reports_are_throttled_within_a_stage_but_every_stage_is_reported(
    store, add_job, face_W
) -> None:
    job_id = add_job(face_W)
    assert store.start(job_id)
    clock = FakeClock()
    reporter = ProgressReporter(store, job_id, interval=0.5, clock=clock)

    assert reporter(progress("validating")) is False
    assert stored_progress(store, job_id)["stage"] == "validating"
    clock.now += 0.01
    reporter(progress("rotations"))
    assert stored_progress(store, job_id)["stage"] == "rotations"  # stage change: at once
    clock.now += 0.01
    reporter(progress("iterating", 1, gap=0.5))
    assert stored_progress(store, job_id)["iteration"] == 1
    for iteration in range(2, 10):  # 0.4 s in all: nothing written
        clock.now += 0.05
        assert reporter(progress("iterating", iteration, gap=0.1)) is False
    assert stored_progress(store, job_id)["iteration"] == 1
    clock.now += 0.2  # 0.6 s after the last report
    reporter(progress("iterating", 10, gap=0.01))
    assert stored_progress(store, job_id)["iteration"] == 10
    assert stored_progress(store, job_id)["gap"] == 0.01
    assert reporter.reports == 4


def test_nan_is_stored_as_null() -> None:
    fields = progress_fields(progress("rotations"))
    assert fields["gap"] is None and fields["eta"] is None and fields["rho"] == 0.01


def test_cancellation_is_seen_at_the_next_call(store, add_job, face_W) -> None:
    job_id = add_job(face_W)
    store.start(job_id)
    clock = FakeClock()
    reporter = ProgressReporter(store, job_id, clock=clock)
    assert reporter(progress("iterating", 1)) is False
    before = stored_progress(store, job_id)

    assert store.cancel(job_id)
    clock.now += 0.01  # within the throttle interval: only the status is read
    assert reporter(progress("iterating", 2)) is True
    assert reporter.stopped_because is JobStatus.CANCELLED
    clock.now += 1.0  # a due report is refused too: a cancelled job's progress stays put
    assert reporter(progress("iterating", 3)) is True
    assert stored_progress(store, job_id) == before


def test_deleted_job_stops_and_is_not_recreated(store, add_job, face_W) -> None:
    job_id = add_job(face_W)
    store.start(job_id)
    clock = FakeClock()
    reporter = ProgressReporter(store, job_id, clock=clock)
    store.remove(job_id)
    clock.now += 1.0
    assert reporter(progress("iterating", 5)) is True
    assert reporter.stopped_because is None
    assert store.connection.exists(record_key(job_id)) == 0
