"""The worker process's loop: it outlives a Redis that goes away (real Redis)."""

from __future__ import annotations

import signal
import threading
import time

import pytest
from redis import Redis
from redis.exceptions import ConnectionError as RedisConnectionError
from rq import Queue

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


@pytest.fixture
def restore_signal_handlers():
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


def test_a_cold_shutdown_that_goes_ahead_ignores_further_signals(
    monkeypatch, restore_signal_handlers
) -> None:
    """``moju serve`` repeats the cold-shutdown signal until the worker exits; a repeat must
    not cut short the recording of the interrupted job."""

    def going_down(self, signum, frame) -> None:
        raise SystemExit()

    monkeypatch.setattr(runner.Worker, "request_force_stop", going_down)
    worker = runner.MojuWorker.__new__(runner.MojuWorker)
    with pytest.raises(SystemExit):
        worker.request_force_stop(signal.SIGTERM, None)
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN
    assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_a_signal_rq_ignores_leaves_the_worker_listening(
    monkeypatch, restore_signal_handlers
) -> None:
    """Within a second of the warm shutdown RQ ignores the signal: the next one must still
    reach the cold shutdown."""
    monkeypatch.setattr(runner.Worker, "request_force_stop", lambda self, signum, frame: None)
    worker = runner.MojuWorker.__new__(runner.MojuWorker)
    worker.request_force_stop(signal.SIGTERM, None)
    for sig in (signal.SIGINT, signal.SIGTERM):
        assert signal.getsignal(sig) == worker.request_force_stop


def test_unsubscribing_does_not_wait_for_the_listeners_long_read(redis_url: str) -> None:
    """The listener thread has already read the unsubscription's reply (what a loaded machine
    makes likely) and waits up to 60 s for a subscription: leaving the channel must still end
    at once (RQ 3.0's own unsubscribe waited those 60 s with redis-py 8.2, past the shutdown
    deadline of ``moju serve`` and of the tests that stop a worker)."""
    connection = Redis.from_url(redis_url)
    worker = runner.MojuWorker(
        [Queue("unsubscribe-test", connection=connection)],
        connection=connection,
        name="unsubscribing",
    )
    worker.subscribe()
    until = time.monotonic() + 10
    while not worker.pubsub.subscribed and time.monotonic() < until:
        time.sleep(0.01)
    assert worker.pubsub.subscribed
    worker.pubsub.unsubscribe()  # the reply reaches the listener before the stop below
    while worker.pubsub.subscribed and time.monotonic() < until:
        time.sleep(0.01)
    assert not worker.pubsub.subscribed

    leaving = threading.Thread(target=worker.unsubscribe, daemon=True)
    leaving.start()
    leaving.join(timeout=10)
    assert not leaving.is_alive()
    connection.close()
