"""worker.rq_log: RQ's "Job OK" line names the outcome of a job that did not finish."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest
from redis import Redis
from rq import Queue, SimpleWorker

from worker import rq_log


class _Lines(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@pytest.fixture
def rq_lines(redis_url: str) -> Iterator[list[str]]:
    """Messages of RQ's worker logger while the test runs, with the filter installed."""
    logger = logging.getLogger(rq_log.RQ_WORKER_LOGGER)
    handler = _Lines()
    logger.addHandler(handler)
    rq_log.install()
    try:
        yield handler.lines
    finally:
        logger.removeHandler(handler)
        rq_log.note_outcome("", "finished")


def _run(redis_url: str, rq_id: str, status: str) -> None:
    """Run one RQ job that returns after noting ``status``, as run_reconstruction does."""
    connection = Redis.from_url(redis_url)
    queue = Queue("rq-log-test", connection=connection)
    queue.enqueue(rq_log.note_outcome, rq_id, status, job_id=rq_id)
    SimpleWorker([queue], connection=connection).work(burst=True, logging_level="INFO")


def test_a_cancelled_job_is_not_logged_as_ok(redis_url: str, rq_lines: list[str]) -> None:
    _run(redis_url, "job-cancelled", "cancelled")
    about_it = [line for line in rq_lines if "job-cancelled" in line]
    assert any("Job ended, cancelled (job-cancelled)" in line for line in about_it), rq_lines
    assert any(line.startswith("Job job-cancelled returned, cancelled") for line in about_it)
    assert not any("Job OK" in line or "Successfully" in line for line in about_it), about_it


def test_a_finished_job_keeps_rq_s_lines(redis_url: str, rq_lines: list[str]) -> None:
    _run(redis_url, "job-finished", "finished")
    about_it = [line for line in rq_lines if "job-finished" in line]
    assert any("Job OK (job-finished)" in line for line in about_it), rq_lines
