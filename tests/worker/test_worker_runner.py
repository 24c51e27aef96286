"""The worker process's loop: it outlives a Redis that goes away (real Redis)."""

from __future__ import annotations

import pytest
from redis.exceptions import ConnectionError as RedisConnectionError

from service.settings import get_settings
from worker import runner


@pytest.fixture
def worker_environment(monkeypatch, redis_url: str, tmp_path):
    monkeypatch.setenv("MOJU_REDIS_URL", redis_url)
    monkeypatch.setenv("MOJU_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("MOJU_WORKER_NICENESS", "0")
    get_settings.cache_clear()
    yield
    get_settings.cache_clear()


def test_worker_reconnects_when_redis_goes_away_between_jobs(
    monkeypatch, worker_environment
) -> None:
    """RQ lets a connection error in its bookkeeping end ``work()`` (seen in CI when Redis
    was restarted right after a job): the worker must wait for Redis and work on."""
    calls = []

    def work(self, burst: bool = False, logging_level: str = "INFO") -> bool:
        calls.append(self.name)
        if len(calls) == 1:
            raise RedisConnectionError("Error 111 connecting to 127.0.0.1. Connection refused.")
        return False

    monkeypatch.setattr(runner.MojuWorker, "work", work)
    assert runner.run_worker(burst=True, name="reconnecting") is False
    assert calls == ["reconnecting", "reconnecting"]  # the same name registers again


def test_a_connection_error_during_a_job_is_not_recorded_as_a_shutdown(monkeypatch) -> None:
    def failing_execute(self, job, queue) -> None:
        raise RedisConnectionError("Connection closed by server.")

    monkeypatch.setattr(runner.Worker, "execute_job", failing_execute)
    worker = runner.MojuWorker.__new__(runner.MojuWorker)
    with pytest.raises(RedisConnectionError):
        worker.execute_job(type("Job", (), {"id": "rq-job"})(), None)
    assert worker.interrupted_job_id is None
