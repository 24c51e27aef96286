"""Job records in Redis: the one place that knows a job's state, progress and outcome.

Keys (all under the ``moju:`` prefix, next to RQ's own ``rq:`` keys):

* ``moju:job:<uuid>``: a hash with the fields of :class:`service.schemas.JobRecord`, JSON
  where the value is structured, plus ``owner`` (the submitting API key's owner id, see
  :mod:`service.auth`; empty without keys), ``attempts`` (how many times a worker started
  it) and ``rq_job`` (the RQ job id of the current attempt, when it is not the job id);
* ``moju:jobs`` (anonymous jobs) and ``moju:jobs:<owner>``: sorted sets of job ids scored by
  creation time, for each owner's newest-first list;
* ``moju:active`` and ``moju:active:<owner>``: each owner's queued and running jobs (scored
  by submission time), for the per-key limit (``MOJU_MAX_QUEUED_JOBS_PER_KEY``);
* ``moju:running``: the running jobs (scored by start time), for the watchdog;
* ``moju:lease:<uuid>``: the running attempt's number, with a TTL its work horse renews
  (``MOJU_HEARTBEAT_INTERVAL``, ``MOJU_HEARTBEAT_TTL``). A running job without a lease has
  lost its worker (see :mod:`service.watchdog`).

Every state change is a compare-and-set in a Lua script (:data:`_TRANSITION`, :data:`_START`),
so the API cancelling a job and its worker finishing it at the same moment cannot both win, a
worker can never re-create the record of a job that was deleted under it (``HSET`` on a
missing key would), and a worker whose attempt was given up (its lease expired and the job was
queued again or failed) cannot change the job any more: its writes name its attempt number. A
record gets a TTL (``MOJU_RESULT_TTL``) when its job ends; index entries of expired records
are pruned lazily. The scripts reach the owner's keys by name, which a Redis Cluster would
refuse; RQ needs a single Redis (or a primary with replicas) anyway.

RQ runs the jobs; its own job hash (``rq:job:<id>``) is consulted only to notice jobs whose
work horse died under a living worker before it could record an outcome (see
:func:`reconcile`), and only through :mod:`service.rq_internals`.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Mapping
from datetime import datetime, timezone
from typing import Any, NamedTuple
from uuid import UUID

import anyio.to_thread
from redis import Redis
from redis.asyncio import Redis as AsyncRedis
from redis.client import Pipeline
from redis.exceptions import WatchError
from rq.job import Job as RQJob

from service.queueing import job_id_of_rq_job, rq_job_id
from service.rq_internals import RQ_ALIVE, parse_rq_state, read_rq_state, started_rq_job_ids
from service.schemas import InputSummary, JobRecord
from service.states import ACTIVE_STATES, JobStatus

logger = logging.getLogger(__name__)

INDEX_KEY = "moju:jobs"
RUNNING_KEY = "moju:running"
_ACTIVE_KEY = "moju:active"
_RECORD_PREFIX = "moju:job:"
_LEASE_PREFIX = "moju:lease:"

#: Seconds after which a reservation of a queue slot without a job record is taken for the
#: leftover of an API process that died while submitting (see :meth:`JobStore.reserve`).
RESERVATION_GRACE_SECONDS = 60.0

# Keys of an owner, computed inside the scripts from the record's 'owner' field.
_OWNER_KEYS = """
local function active_key(record)
  local owner = redis.call('HGET', record, 'owner')
  if owner and owner ~= '' then return 'moju:active:' .. owner end
  return 'moju:active'
end
"""

# KEYS[1]: record; KEYS[2]: lease; KEYS[3]: running set. ARGV[1]: job id; ARGV[2]: new
# status; ARGV[3]: allowed current statuses, space separated; ARGV[4]: TTL in seconds to set
# when the new status is terminal (0: not terminal); ARGV[5]: the attempt the caller runs (''
# for any); ARGV[6..]: field, value pairs to set as well.
# Returns {1, previous status} on success, {0, current status, or '' when the record is gone,
# or 'superseded' when another attempt runs the job} when refused.
_TRANSITION = (
    _OWNER_KEYS
    + """
local current = redis.call('HGET', KEYS[1], 'status')
if not current then return {0, ''} end
if not string.find(' ' .. ARGV[3] .. ' ', ' ' .. current .. ' ', 1, true) then
    return {0, current}
end
if ARGV[5] ~= '' and redis.call('HGET', KEYS[1], 'attempts') ~= ARGV[5] then
    return {0, 'superseded'}
end
redis.call('HSET', KEYS[1], 'status', ARGV[2])
if #ARGV > 5 then redis.call('HSET', KEYS[1], unpack(ARGV, 6)) end
local ttl = tonumber(ARGV[4])
if ttl > 0 then
    redis.call('EXPIRE', KEYS[1], ttl)
    redis.call('DEL', KEYS[2])
    redis.call('ZREM', KEYS[3], ARGV[1])
    redis.call('ZREM', active_key(KEYS[1]), ARGV[1])
end
return {1, current}
"""
)

# KEYS[1]: record; KEYS[2]: lease; KEYS[3]: running set. ARGV[1]: job id; ARGV[2]: now
# (epoch seconds); ARGV[3]: lease TTL in milliseconds.
# queued -> running as a new attempt: returns {1, attempt} or {0, current status or ''}.
_START = """
local current = redis.call('HGET', KEYS[1], 'status')
if current ~= 'queued' then return {0, current or ''} end
local attempt = redis.call('HINCRBY', KEYS[1], 'attempts', 1)
redis.call('HSET', KEYS[1], 'status', 'running', 'started_at', ARGV[2])
redis.call('HDEL', KEYS[1], 'progress')
redis.call('SET', KEYS[2], attempt, 'PX', ARGV[3])
redis.call('ZADD', KEYS[3], ARGV[2], ARGV[1])
return {1, attempt}
"""

# KEYS[1]: record. ARGV[1]: progress JSON; ARGV[2]: the running status; ARGV[3]: the
# reporting attempt ('' for any). Stores the progress only while this attempt runs; returns
# the current status ('' when the record is gone, 'superseded' when another attempt runs it)
# so that the worker learns of a cancellation.
_PROGRESS = """
local current = redis.call('HGET', KEYS[1], 'status')
if not current then return '' end
if current == ARGV[2] then
    if ARGV[3] ~= '' and redis.call('HGET', KEYS[1], 'attempts') ~= ARGV[3] then
        return 'superseded'
    end
    redis.call('HSET', KEYS[1], 'progress', ARGV[1])
end
return current
"""

# KEYS[1]: lease; KEYS[2]: record. ARGV[1]: attempt; ARGV[2]: lease TTL in milliseconds.
# Renews (or re-creates, after a late beat) the lease while this attempt still runs the job;
# returns 0 when it does not (ended, cancelled, or given up by the watchdog).
_HEARTBEAT = """
if redis.call('HGET', KEYS[2], 'status') ~= 'running' then return 0 end
if redis.call('HGET', KEYS[2], 'attempts') ~= ARGV[1] then return 0 end
redis.call('SET', KEYS[1], ARGV[1], 'PX', ARGV[2])
return 1
"""

# KEYS[1]: the owner's active set. ARGV[1]: job id; ARGV[2]: now; ARGV[3]: limit (0: none).
_RESERVE = """
local limit = tonumber(ARGV[3])
if limit > 0 and redis.call('ZCARD', KEYS[1]) >= limit then return 0 end
redis.call('ZADD', KEYS[1], ARGV[2], ARGV[1])
return 1
"""


def record_key(job_id: UUID) -> str:
    """Redis key of a job's record."""
    return f"{_RECORD_PREFIX}{job_id}"


def lease_key(job_id: UUID) -> str:
    """Redis key of a running job's lease (renewed by its work horse's heartbeats)."""
    return f"{_LEASE_PREFIX}{job_id}"


def _owned_by(fields: dict, owner: str | None) -> bool:
    """Whether a raw record belongs to ``owner`` (None: anyone's record will do)."""
    return owner is None or (_text(fields.get(b"owner")) or "") == owner


def index_key(owner: str) -> str:
    """Redis key of an owner's job list ("" is the anonymous owner)."""
    return f"{INDEX_KEY}:{owner}" if owner else INDEX_KEY


def active_key(owner: str) -> str:
    """Redis key of an owner's queued and running jobs."""
    return f"{_ACTIVE_KEY}:{owner}" if owner else _ACTIVE_KEY


def _timestamp(value: str | None) -> datetime | None:
    return None if value is None else datetime.fromtimestamp(float(value), tz=timezone.utc)


def _text(value: bytes | str | None) -> str | None:
    return value.decode() if isinstance(value, bytes) else value


def _decode(job_id: UUID, raw_fields: Mapping[bytes, bytes]) -> JobRecord:
    """Build a record from the hash fields as Redis returns them."""
    fields = {_text(name): _text(value) for name, value in raw_fields.items()}

    def structured(name: str) -> Any:
        value = fields.get(name)
        return None if value is None else json.loads(value)

    record = JobRecord(
        id=job_id,
        status=JobStatus(fields["status"]),
        created_at=_timestamp(fields["created_at"]),
        started_at=_timestamp(fields.get("started_at")),
        ended_at=_timestamp(fields.get("ended_at")),
        parameters=structured("parameters"),
        input=structured("input"),
        progress=structured("progress"),
        error=fields.get("error"),
        result=structured("result"),
        attempts=int(fields.get("attempts") or 0),
    )
    return record.owned_by(fields.get("owner") or "")


class Liveness(NamedTuple):
    """What Redis says about an active job besides its record."""

    #: RQ's status of the RQ job of the current attempt (None: RQ has no such job).
    rq_status: str | None
    #: When a worker took that RQ job (epoch seconds), None if none did.
    rq_started: float | None
    #: Whether the job's lease exists (renewed by the work horse while the job runs).
    lease: bool


def _liveness(rq_fields: list[Any], lease: Any) -> Liveness:
    """A job's liveness from the reply to :func:`read_rq_state` and its lease's existence."""
    state = parse_rq_state(rq_fields)
    return Liveness(state.status, state.started, bool(lease))


def worker_lost(record: JobRecord, live: Liveness, lease_seconds: float) -> bool:
    """True when the job's worker is gone: no lease while it runs, or taken from the queue by
    a worker that never started it (the worker died between RQ's dequeue and the start)."""
    if record.status is JobStatus.RUNNING:
        return not live.lease
    if record.status is JobStatus.QUEUED and live.rq_status == "started":
        return live.rq_started is not None and time.time() - live.rq_started > lease_seconds
    return False


def _needs_check(record: JobRecord, live: Liveness, lease_seconds: float) -> bool:
    """True when an active job may no longer be able to end normally.

    Either RQ no longer counts the job as waiting or running, or its worker is gone
    (:func:`worker_lost`).
    """
    if record.status not in ACTIVE_STATES:
        return False
    if live.rq_status not in RQ_ALIVE:
        return True
    return worker_lost(record, live, lease_seconds)


def reconcile(record: JobRecord, rq_status: str | None, rq_error: str | None) -> str | None:
    """Why an active job can no longer end normally, judged from RQ's view of it; else None.

    A worker records every outcome it can see itself (success, failure, cancellation, time
    limit). What it cannot record is its own death: a work horse killed by the kernel (out
    of memory), by ``rq`` (cold shutdown) or an RQ job removed from Redis. Those leave our
    record ``queued`` or ``running`` while RQ knows better.
    """
    if record.status not in ACTIVE_STATES:
        return None
    if rq_status is None:
        return (
            "the job queue lost this job (its queue entry was removed from Redis, e.g. by a "
            "Redis restart without persistence); submit it again"
        )
    if rq_status in RQ_ALIVE:
        return None
    if rq_status == "stopped":
        return "an operator stopped this job (rq stop command); submit it again if needed"
    if rq_status == "canceled":
        return "the job was cancelled in the queue by an operator (rq cancel)"
    detail = f" (worker report: {rq_error.strip().splitlines()[-1]})" if rq_error else ""
    return (
        "the worker running this job stopped before recording an outcome, e.g. because it "
        "was killed or ran out of memory" + detail + "; submit the job again, with fewer "
        "points if memory is short"
    )


#: Called with a running job's record when its lease expired: decides whether the job is
#: queued again or failed (see :mod:`service.watchdog`).
LostJobHandler = Callable[[JobRecord], None]


class JobStore:
    """Job records in Redis.

    Parameters
    ----------
    connection : redis.Redis
        A client returning bytes (RQ needs that; this class decodes what it reads).
    retention_seconds : int
        TTL given to a record when its job ends (finished, failed or cancelled).
    async_connection : redis.asyncio.Redis, optional
        The same server through an asyncio client, for :meth:`get_async` (the API only).
    lost_job_handler : callable, optional
        What to do with a job whose worker is gone (:func:`worker_lost`), when a read notices
        it; without one such jobs are left to the watchdog.
    lease_seconds : float
        ``MOJU_HEARTBEAT_TTL``: how long a job taken from the queue may stay unstarted.
    """

    def __init__(
        self,
        connection: Redis,
        *,
        retention_seconds: int,
        async_connection: AsyncRedis | None = None,
        lost_job_handler: LostJobHandler | None = None,
        lease_seconds: float = 30.0,
    ) -> None:
        self.connection = connection
        self.async_connection = async_connection
        self.retention_seconds = retention_seconds
        self.lost_job_handler = lost_job_handler
        self.lease_seconds = lease_seconds
        self._transition = connection.register_script(_TRANSITION)
        self._start = connection.register_script(_START)
        self._progress = connection.register_script(_PROGRESS)
        self._heartbeat = connection.register_script(_HEARTBEAT)
        self._reserve = connection.register_script(_RESERVE)

    # ---------------------------------------------------------------- creation and reading

    def add(self, record: JobRecord, pipeline: Pipeline) -> None:
        """Queue the commands that store a new record on ``pipeline`` (the caller executes).

        The API enqueues the RQ job on the same transaction, so a worker can never see a
        job without its record, nor a record exist without its queue entry. The record's
        owner (``record.owner``) decides which job list it joins.
        """
        fields = {
            "status": record.status.value,
            "created_at": repr(record.created_at.timestamp()),
            "parameters": record.parameters.model_dump_json(exclude_unset=True),
            "input": record.input.model_dump_json(),
            "owner": record.owner,
            "attempts": "0",
            "enqueued": "1",
        }
        pipeline.hset(record_key(record.id), mapping=fields)
        pipeline.zadd(index_key(record.owner), {str(record.id): record.created_at.timestamp()})

    def _read_pipeline(self, pipe: Any, job_id: UUID) -> None:
        pipe.hgetall(record_key(job_id))
        read_rq_state(pipe, str(job_id))
        pipe.exists(lease_key(job_id))

    def _liveness_of(
        self, job_id: UUID, fields: Mapping[bytes, bytes], rq_fields: list, lease: Any
    ) -> Liveness:
        """RQ's view of the job's current attempt (a retry is another RQ job), and its lease."""
        current = _text(fields.get(b"rq_job"))
        if current and current != str(job_id):
            rq_fields = read_rq_state(self.connection, current)
        return _liveness(rq_fields, lease)

    def get(
        self, job_id: UUID, *, reconcile_with_rq: bool = True, owner: str | None = None
    ) -> JobRecord | None:
        """The record of a job, or None when there is none (never existed, deleted, expired)
        or, with ``owner``, when it belongs to another owner: found out before the record is
        decoded, so that another key's job costs no more to refuse than an unknown id.

        Active records are checked against RQ and their lease in the same round trip; a job
        whose worker died is dealt with here, once (see :func:`reconcile` and
        :mod:`service.watchdog`). The worker running the job reads it with
        ``reconcile_with_rq=False``: it knows it is alive.
        """
        if not reconcile_with_rq:
            fields = self.connection.hgetall(record_key(job_id))
            return _decode(job_id, fields) if fields else None
        pipe = self.connection.pipeline(transaction=False)
        self._read_pipeline(pipe, job_id)
        fields, rq_fields, lease = pipe.execute()
        if not fields or not _owned_by(fields, owner):
            return None
        record = _decode(job_id, fields)
        if record.status not in ACTIVE_STATES:
            return record
        return self._checked(record, self._liveness_of(job_id, fields, rq_fields, lease))

    async def get_async(self, job_id: UUID, owner: str | None = None) -> JobRecord | None:
        """:meth:`get` for the event loop, through the asyncio client.

        The API's hottest requests (status polls, event streams) read a record and nothing
        else; doing that without a trip through the thread pool halves their CPU cost. The
        rare reconciliation writes still go through the synchronous client, in a thread.
        """
        if self.async_connection is None:
            raise RuntimeError("this JobStore was made without an asyncio connection")
        async with self.async_connection.pipeline(transaction=False) as pipe:
            self._read_pipeline(pipe, job_id)
            fields, rq_fields, lease = await pipe.execute()
        if not fields or not _owned_by(fields, owner):
            return None
        record = _decode(job_id, fields)
        if record.status not in ACTIVE_STATES:
            return record
        current = _text(fields.get(b"rq_job"))
        if current and current != str(job_id):
            rq_fields = await read_rq_state(self.async_connection, current)
        live = _liveness(rq_fields, lease)
        if not _needs_check(record, live, self.lease_seconds):
            return record
        return await anyio.to_thread.run_sync(self._checked, record, live)

    def page(self, limit: int, offset: int, owner: str = "") -> tuple[list[JobRecord], int]:
        """An owner's records newest first: ``limit`` from ``offset``, and their count."""
        index = index_key(owner)
        pipe = self.connection.pipeline(transaction=False)
        pipe.zrevrange(index, offset, offset + limit - 1)
        pipe.zcard(index)
        raw_ids, total = pipe.execute()
        ids = [_text(raw_id) for raw_id in raw_ids]
        if not ids:
            return [], total
        pipe = self.connection.pipeline(transaction=False)
        for raw_id in ids:
            self._read_pipeline(pipe, UUID(raw_id))
        replies = pipe.execute()
        records, expired = [], []
        for index_number, raw_id in enumerate(ids):
            fields, rq_fields, lease = replies[3 * index_number : 3 * index_number + 3]
            if not fields:
                expired.append(raw_id)
                continue
            job_id = UUID(raw_id)
            record = _decode(job_id, fields)
            if record.status in ACTIVE_STATES:
                live = self._liveness_of(job_id, fields, rq_fields, lease)
                record = self._checked(record, live)
            records.append(record)
        if expired:
            self.connection.zrem(index, *expired)
            total -= len(expired)
        return records, total

    def status(self, job_id: UUID) -> JobStatus | None:
        """Current status without reconciliation (cheap: one HGET), or None."""
        value = self.connection.hget(record_key(job_id), "status")
        return None if value is None else JobStatus(_text(value))

    def _checked(self, record: JobRecord, live: Liveness) -> JobRecord:
        if not _needs_check(record, live, self.lease_seconds):
            return record
        rq_status = live.rq_status
        rq_error = None
        if rq_status == "failed":
            try:
                rq_id = self.rq_job_of(record.id)
                latest = RQJob.fetch(rq_id, connection=self.connection).latest_result()
                rq_error = getattr(latest, "exc_string", None)
            except Exception:  # the reason is a nicety; never fail a read because of it
                logger.debug("no RQ failure details for job %s", record.id, exc_info=True)
        reason = reconcile(record, rq_status, rq_error)
        if reason is not None:
            logger.warning("job %s: %s", record.id, reason)
            if rq_status == "canceled":
                self.cancel(record.id, reason=reason)
            else:
                self.fail(record.id, reason)
        elif worker_lost(record, live, self.lease_seconds):
            if self.lost_job_handler is None:
                return record
            self.lost_job_handler(record)
        else:
            return record
        return self._reread(record.id) or record

    def _reread(self, job_id: UUID) -> JobRecord | None:
        fields = self.connection.hgetall(record_key(job_id))
        return _decode(job_id, fields) if fields else None

    def rq_job_of(self, job_id: UUID) -> str:
        """The RQ job id of the job's current attempt."""
        return _text(self.connection.hget(record_key(job_id), "rq_job")) or str(job_id)

    # ---------------------------------------------------------------- state changes

    def _change(
        self,
        job_id: UUID,
        new: JobStatus,
        allowed: set[JobStatus] | frozenset[JobStatus],
        fields: Mapping[str, str],
        attempt: int | None = None,
    ) -> bool:
        ttl = self.retention_seconds if new.is_terminal else 0
        arguments: list[str] = [
            str(job_id),
            new.value,
            " ".join(s.value for s in allowed),
            str(ttl),
            "" if attempt is None else str(attempt),
        ]
        for name, value in fields.items():
            arguments += [name, value]
        keys = [record_key(job_id), lease_key(job_id), RUNNING_KEY]
        changed, previous = self._transition(keys=keys, args=arguments)
        if not changed:
            logger.info(
                "job %s: not moved to %s, it is %s", job_id, new.value, _text(previous) or "gone"
            )
        return bool(changed)

    def start(self, job_id: UUID, *, lease_seconds: float = 30.0) -> int | None:
        """queued -> running as a new attempt, with a lease of ``lease_seconds``.

        Returns the attempt number (1 for the first start), or None when the job is no
        longer queued (e.g. cancelled). The worker renews the lease with :meth:`heartbeat`.
        """
        keys = [record_key(job_id), lease_key(job_id), RUNNING_KEY]
        arguments = [str(job_id), repr(time.time()), str(max(1, int(lease_seconds * 1000)))]
        started, value = self._start(keys=keys, args=arguments)
        if not started:
            logger.info("job %s: not started, it is %s", job_id, _text(value) or "gone")
            return None
        return int(value)

    def heartbeat(self, job_id: UUID, attempt: int, *, lease_seconds: float) -> bool:
        """Renew the lease of a running attempt; False when it no longer runs the job."""
        keys = [lease_key(job_id), record_key(job_id)]
        arguments = [str(attempt), str(max(1, int(lease_seconds * 1000)))]
        return bool(self._heartbeat(keys=keys, args=arguments))

    def report_progress(
        self, job_id: UUID, progress: Mapping[str, Any], attempt: int | None = None
    ) -> JobStatus | None:
        """Store the latest progress of a running job; return the job's current status.

        The returned status is how a worker learns that its job was cancelled (anything
        but ``running``) or deleted, or that its attempt was given up (both None), without
        a second round trip.
        """
        arguments = [
            json.dumps(progress),
            JobStatus.RUNNING.value,
            "" if attempt is None else str(attempt),
        ]
        current = _text(self._progress(keys=[record_key(job_id)], args=arguments))
        if not current or current == "superseded":
            return None
        return JobStatus(current)

    def finish(
        self,
        job_id: UUID,
        summary: Mapping[str, Any],
        progress: Mapping,
        attempt: int | None = None,
        input_summary: InputSummary | None = None,
    ) -> bool:
        """running -> finished, with the result summary and the final progress.

        ``input_summary`` replaces the job's ``input`` when the worker learned more about it
        than the upload told (a video job: the points actually tracked and observed).
        """
        fields = {
            "ended_at": repr(time.time()),
            "result": json.dumps(summary),
            "progress": json.dumps(progress),
        }
        if input_summary is not None:
            fields["input"] = input_summary.model_dump_json()
        return self._change(job_id, JobStatus.FINISHED, {JobStatus.RUNNING}, fields, attempt)

    def fail(self, job_id: UUID, error: str, attempt: int | None = None) -> bool:
        """queued or running -> failed, with a message for the user.

        With ``attempt``, only while that attempt runs the job (a worker failing its job).
        """
        fields = {"ended_at": repr(time.time()), "error": error}
        allowed = ACTIVE_STATES if attempt is None else {JobStatus.RUNNING}
        return self._change(job_id, JobStatus.FAILED, allowed, fields, attempt)

    def cancel(self, job_id: UUID, *, reason: str | None = None) -> bool:
        """queued or running -> cancelled. A running worker notices at its next report.

        ``reason`` is stored as the job's ``error`` when someone other than the user
        cancelled it.
        """
        fields = {"ended_at": repr(time.time())}
        if reason is not None:
            fields["error"] = reason
        return self._change(job_id, JobStatus.CANCELLED, ACTIVE_STATES, fields)

    def give_up(
        self,
        record: JobRecord,
        *,
        retries: int,
        requeue: Callable[[Pipeline, str], None],
        error: str,
    ) -> str | None:
        """Take a job away from its lost worker: queue it again, or fail it.

        The job is either running without a lease, or queued but taken from the queue by a
        worker that never started it (:func:`worker_lost`). Each time a job is given to the
        queue counts (its submission is the first); while that count is at most
        ``retries``, ``requeue(pipeline, rq_id)`` enqueues it once more, as RQ job ``rq_id``,
        on the same transaction; otherwise the job fails with ``error``.

        This is an optimistic transaction on the record and the lease: a late heartbeat, a
        start, a cancellation, or another API process doing the same, makes it a no-op.
        Returns ``"requeued"``, ``"failed"``, or None when nothing was done.
        """
        job_id = record.id
        key, lease = record_key(job_id), lease_key(job_id)
        with self.connection.pipeline(transaction=True) as pipe:
            try:
                pipe.watch(key, lease)
                status, attempts, owner, enqueued, rq_job = pipe.hmget(
                    key, "status", "attempts", "owner", "enqueued", "rq_job"
                )
                rq_job = _text(rq_job) or str(job_id)
                live = _liveness(read_rq_state(pipe, rq_job), pipe.exists(lease))
                if _text(status) != record.status.value or int(attempts or 0) != record.attempts:
                    return None  # it moved on since it was read
                if not worker_lost(record, live, self.lease_seconds):
                    return None
                times_queued = int(enqueued or 1)
                pipe.multi()
                pipe.zrem(RUNNING_KEY, str(job_id))
                if times_queued <= retries:
                    rq_id = rq_job_id(job_id, times_queued + 1)
                    fields = {"status": JobStatus.QUEUED.value, "rq_job": rq_id,
                              "enqueued": str(times_queued + 1)}  # fmt: skip
                    pipe.hset(key, mapping=fields)
                    pipe.hdel(key, "started_at", "progress")
                    requeue(pipe, rq_id)
                    outcome = "requeued"
                else:
                    fields = {
                        "status": JobStatus.FAILED.value,
                        "ended_at": repr(time.time()),
                        "error": error,
                    }
                    pipe.hset(key, mapping=fields)
                    pipe.expire(key, self.retention_seconds)
                    pipe.zrem(active_key(_text(owner) or ""), str(job_id))
                    outcome = "failed"
                pipe.execute()
            except WatchError:
                return None
        return outcome

    def times_queued(self, job_id: UUID) -> int:
        """How many times the job was given to the queue (1 unless a lost worker's job)."""
        return int(self.connection.hget(record_key(job_id), "enqueued") or 1)

    def remove(self, job_id: UUID, owner: str = "") -> None:
        """Delete the record and its index entry."""
        pipe = self.connection.pipeline()
        pipe.delete(record_key(job_id), lease_key(job_id))
        pipe.zrem(index_key(owner), str(job_id))
        pipe.zrem(active_key(owner), str(job_id))
        pipe.zrem(RUNNING_KEY, str(job_id))
        pipe.execute()

    # ---------------------------------------------------------------- queue slots per owner

    def reserve(self, owner: str, job_id: UUID, limit: int) -> bool:
        """Take one of the owner's ``limit`` slots for queued or running jobs (0: no limit).

        The slot is freed when the job ends (the transition scripts), or by
        :meth:`release` when the submission fails before the job is stored. When the owner
        is at the limit, slots held by submissions that never stored their job (an API
        process that died halfway) are reclaimed once they are older than
        :data:`RESERVATION_GRACE_SECONDS`.
        """
        key = active_key(owner)
        arguments = [str(job_id), repr(time.time()), str(limit)]
        if self._reserve(keys=[key], args=arguments):
            return True
        if self._reclaim_stale_slots(key) == 0:
            return False
        return bool(self._reserve(keys=[key], args=arguments))

    def _reclaim_stale_slots(self, key: str) -> int:
        old = self.connection.zrangebyscore(key, 0, time.time() - RESERVATION_GRACE_SECONDS)
        if not old:
            return 0
        pipe = self.connection.pipeline(transaction=False)
        for raw_id in old:
            pipe.hget(f"{_RECORD_PREFIX}{_text(raw_id)}", "status")
        statuses = pipe.execute()
        active = {status.value for status in ACTIVE_STATES}
        stale = [
            raw_id for raw_id, status in zip(old, statuses, strict=True)
            if _text(status) not in active
        ]  # fmt: skip
        if stale:
            self.connection.zrem(key, *stale)
            logger.warning("reclaimed %d queue slot(s) of submissions that never completed",
                           len(stale))  # fmt: skip
        return len(stale)

    def release(self, owner: str, job_id: UUID) -> None:
        """Give back a slot taken by :meth:`reserve` for a job that was not stored."""
        self.connection.zrem(active_key(owner), str(job_id))

    def active_count(self, owner: str) -> int:
        """How many queued or running jobs the owner has."""
        return int(self.connection.zcard(active_key(owner)))

    # ---------------------------------------------------------------- housekeeping

    def running_without_lease(self) -> list[UUID]:
        """Running jobs whose lease expired: their worker is gone (see service.watchdog)."""
        ids = [_text(raw_id) for raw_id in self.connection.zrange(RUNNING_KEY, 0, -1)]
        if not ids:
            return []
        pipe = self.connection.pipeline(transaction=False)
        for raw_id in ids:
            pipe.exists(f"{_LEASE_PREFIX}{raw_id}")
        alive = pipe.execute()
        return [UUID(raw_id) for raw_id, found in zip(ids, alive, strict=True) if not found]

    def taken_but_not_started(self, queue_name: str) -> list[UUID]:
        """Jobs a worker took from the RQ queue that are still ``queued`` in their record.

        Normally a job is in this state for the few milliseconds between RQ's dequeue and
        the start in the work horse; the caller reads each one (which judges, with RQ's
        start time, whether its worker is gone).
        """
        rq_ids = started_rq_job_ids(queue_name, self.connection)
        ids = [job_id for job_id in map(job_id_of_rq_job, rq_ids) if job_id is not None]
        if not ids:
            return []
        pipe = self.connection.pipeline(transaction=False)
        for job_id in ids:
            pipe.hget(record_key(job_id), "status")
        statuses = pipe.execute()
        return [
            job_id
            for job_id, status in zip(ids, statuses, strict=True)
            if _text(status) == JobStatus.QUEUED.value
        ]

    def forget_running(self, job_id: UUID) -> None:
        """Drop a job that has no record any more from the running set."""
        self.connection.zrem(RUNNING_KEY, str(job_id))

    def exists(self, job_ids: list[UUID]) -> list[bool]:
        """Whether each job still has a record."""
        pipe = self.connection.pipeline(transaction=False)
        for job_id in job_ids:
            pipe.exists(record_key(job_id))
        return [bool(found) for found in pipe.execute()]

    def _index_keys(self) -> list[str]:
        keys = {INDEX_KEY}
        keys.update(_text(k) for k in self.connection.scan_iter(match=f"{INDEX_KEY}:*"))
        return sorted(keys)

    def prune_index(self) -> int:
        """Drop index entries (of every owner) whose record expired; return how many."""
        pruned = 0
        for index in self._index_keys():
            ids = [_text(raw_id) for raw_id in self.connection.zrange(index, 0, -1)]
            if not ids:
                continue
            present = self.exists([UUID(raw_id) for raw_id in ids])
            expired = [raw_id for raw_id, found in zip(ids, present, strict=True) if not found]
            if expired:
                self.connection.zrem(index, *expired)
            pruned += len(expired)
        return pruned
