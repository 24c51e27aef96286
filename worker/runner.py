"""The worker process (``moju worker``): RQ's forking worker on the MoJu queue.

RQ forks a "work horse" per job, so a crash or a leak in one job never outlives it; the
solver is imported once in the parent before forking, so each job starts without paying
for the imports of numpy, scipy and scikit-learn again.
"""

from __future__ import annotations

import logging
import os
import signal
import time
from types import FrameType

from redis import Redis
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError
from rq import Queue, Worker
from rq.job import Job as RQJob

from service.connection import connect_redis
from service.job_store import JobStore
from service.log_setup import configure_logging
from service.queueing import job_id_of_rq_job, job_queue
from service.settings import Settings, get_settings
from worker import rq_log

logger = logging.getLogger(__name__)

#: Errors by which a Redis that went away shows itself.
REDIS_DOWN = (RedisConnectionError, RedisTimeoutError)
#: Longest pause between two attempts to reach a Redis that went away (seconds).
MAX_RECONNECT_PAUSE = 5.0

INTERRUPTED = (
    "the worker running this job was shut down before the job ended (service stopped or "
    "restarted); submit the job again"
)


class MojuWorker(Worker):
    """RQ's worker, remembering a job whose execution was interrupted by a shutdown.

    RQ's cold shutdown (a second SIGTERM or Ctrl-C) kills the work horse and leaves the job
    "started" until RQ's own maintenance notices much later; recording the interruption
    here tells the user at once.
    """

    interrupted_job_id: str | None = None

    def request_force_stop(self, signum: int, frame: FrameType | None) -> None:
        """RQ's cold shutdown, deaf to further signals once it goes ahead.

        ``moju serve`` repeats the signal until the worker exits
        (:func:`service.processes.signal_until_exit`); a repeat handled while the worker
        records the interrupted job would cut the recording short. RQ ignores a signal
        within a second of the warm shutdown's: then it returns, and the worker listens again.
        """
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
        super().request_force_stop(signum, frame)  # raises SystemExit when it goes ahead
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self.request_force_stop)

    def unsubscribe(self) -> None:
        """Stop listening on the worker's command channel, within about a second.

        RQ unsubscribes first and then stops its listener thread, counting on the
        unsubscription's reply to wake the thread from its 60-second read. With redis-py 8.2
        the stop waits for the thread to end; if the thread reads that reply before the stop
        clears its running flag, it goes back to waiting for a subscription, and the worker's
        exit (a shutdown, the interrupted job's record) waits the full 60 seconds. Here the
        flag is cleared first, so the reply ends the thread.
        """
        thread = self.pubsub_thread
        if not thread:
            return
        channel = self.pubsub_channel_name
        self.log.info("Worker %s: unsubscribing from channel %s", self.name, channel)
        try:
            thread.stop(timeout=0)  # redis-py 8.2 and later: clear the flag, do not wait
        except TypeError:
            thread.stop()  # earlier redis-py: only clears the flag
        self.pubsub.unsubscribe()
        thread.join(timeout=1)
        self.pubsub.close()

    def execute_job(self, job: RQJob, queue: Queue) -> None:
        """Run one job in a work horse, noting the job if a shutdown interrupts it."""
        try:
            super().execute_job(job, queue)
        except REDIS_DOWN:
            # Redis went away (e.g. during RQ's bookkeeping after the job): not a shutdown;
            # the job's own record says how far it got, and run_worker reconnects.
            raise
        except BaseException:
            self.interrupted_job_id = job.id
            raise


def _record_interruption(worker: MojuWorker, settings: Settings) -> None:
    rq_id = worker.interrupted_job_id
    if rq_id is None:
        return
    job_id = job_id_of_rq_job(rq_id)
    if job_id is None:  # not one of ours (someone else's job on our queue)
        return
    store = JobStore(worker.connection, retention_seconds=settings.result_ttl)
    try:
        if store.rq_job_of(job_id) != rq_id:
            return  # an attempt that had been given up already; another one holds the job
        if store.fail(job_id, INTERRUPTED):
            logger.warning("job %s: interrupted by the worker's shutdown", job_id)
    except REDIS_DOWN as exc:  # the watchdog will find the job without a lease instead
        logger.warning("job %s: interruption not recorded, Redis is unreachable (%s)", job_id, exc)


def _wait_for_redis(connection: Redis) -> None:
    """Block until Redis answers again, with growing pauses (at most MAX_RECONNECT_PAUSE).

    RQ's signal handlers only set flags that its own loop reads; outside that loop the
    defaults are restored, so that Ctrl-C or SIGTERM stops a worker waiting for Redis.
    """
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    pause = 0.25
    while True:
        try:
            connection.ping()
            return
        except REDIS_DOWN:
            time.sleep(pause)
            pause = min(2.0 * pause, MAX_RECONNECT_PAUSE)


def run_worker(*, burst: bool = False, name: str | None = None) -> bool:
    """Take jobs from the queue until stopped (or, with ``burst``, until it is empty).

    Configuration comes from the ``MOJU_*`` environment (:func:`service.settings.get_settings`),
    the same place the job function reads it from in the forked work horses.

    Parameters
    ----------
    burst : bool
        Quit once the queue is empty instead of waiting for more jobs.
    name : str, optional
        Worker name shown by ``rq info``; RQ picks a unique one by default.
    Returns
    -------
    bool
        True when at least one job was run.
    """
    configure_logging()
    rq_log.install()  # before forking: the work horses log RQ's line of each job
    settings = get_settings()
    if settings.worker_niceness:
        os.nice(settings.worker_niceness)  # solving yields the CPU to the API
    connection = connect_redis(settings.require_redis_url())
    import moju_core.solver  # noqa: F401 - preloaded so that forked work horses share it

    ran_jobs = False
    while True:
        worker = MojuWorker(
            [job_queue(connection, settings)],
            connection=connection,
            name=name,
            default_result_ttl=settings.result_ttl,
        )
        try:
            return worker.work(burst=burst, logging_level="INFO") or ran_jobs
        except REDIS_DOWN as exc:
            # RQ lets a connection error that hits its bookkeeping (between jobs, or right
            # after one) end the worker; a Redis restart must not take the workers with it.
            logger.warning("worker: Redis went away (%s); waiting for it to come back", exc)
            ran_jobs = ran_jobs or worker.successful_job_count + worker.failed_job_count > 0
            _wait_for_redis(connection)
            try:
                worker.register_death()  # so that the same name can register again
            except REDIS_DOWN:
                pass
            logger.info("worker: Redis is back; taking jobs again")
        finally:
            _record_interruption(worker, settings)
