"""Every read of RQ's private Redis layout, in one place.

The service mostly goes through RQ's public API (``Queue``, ``Job.fetch``, ``job.cancel()``).
Two reads cannot: the job store checks RQ's view of a job in the same Redis round trip as the
job's own record (a status poll must not cost a second trip, and the watchdog's check runs
inside a ``WATCH`` transaction), so it reads RQ's job hash directly; and the watchdog lists
the jobs RQ counts as started. What those reads assume about RQ (the key of a job's hash,
the names and format of its ``status`` and ``started_at`` fields, the status names, the
started-job registry) is written down here only, and
``tests/service/test_service_rq_internals.py`` fails when an RQ release changes it. The
``rq`` requirement in ``pyproject.toml`` has an upper bound for the same reason.
"""

from __future__ import annotations

from datetime import timezone
from typing import Any, NamedTuple

from redis import Redis
from rq.job import Job as RQJob
from rq.registry import StartedJobRegistry
from rq.utils import utcparse

__all__ = [
    "RQ_ALIVE",
    "RQ_ENDED",
    "RQ_WAITING",
    "RQState",
    "parse_rq_state",
    "read_rq_state",
    "rq_job_key",
    "started_rq_job_ids",
]

#: RQ statuses of a job no worker has taken yet (it can still be taken out of the queue).
RQ_WAITING = frozenset(
    {"created", "queued", "deferred", "scheduled", "rate_limited", "ready_to_enqueue"}
)
#: RQ statuses of a job that is waiting or being run: RQ does not think it has ended.
RQ_ALIVE = RQ_WAITING | {"started"}
#: RQ statuses of a job that has ended, one way or another.
RQ_ENDED = frozenset({"finished", "failed", "stopped", "canceled"})

# Fields of RQ's job hash read here.
_STATUS_FIELD = "status"
_STARTED_FIELD = "started_at"


class RQState(NamedTuple):
    """RQ's view of one RQ job, as read from its hash."""

    #: RQ's status (one of :data:`RQ_ALIVE` or :data:`RQ_ENDED`), None when RQ has no such job.
    status: str | None
    #: When a worker took the job (epoch seconds), None if none did.
    started: float | None


def rq_job_key(rq_id: str) -> str:
    """The Redis key of RQ's hash of job ``rq_id``."""
    return RQJob.key_for(rq_id)


def read_rq_state(client: Any, rq_id: str) -> Any:
    """Ask ``client`` for the raw fields :func:`parse_rq_state` reads.

    ``client`` is a Redis client (sync or asyncio) or a pipeline; the answer (or, for a
    pipeline, the reply at this position) goes to :func:`parse_rq_state`.
    """
    return client.hmget(rq_job_key(rq_id), _STATUS_FIELD, _STARTED_FIELD)


def parse_rq_state(raw: list[Any]) -> RQState:
    """The :class:`RQState` in the reply to :func:`read_rq_state`."""
    status, started = raw
    return RQState(_text(status), _rq_time(started))


def started_rq_job_ids(queue_name: str, connection: Redis) -> list[str]:
    """Ids of the RQ jobs that RQ counts as taken by a worker of ``queue_name``.

    Read without RQ's own cleanup of the registry: what a dead worker left there is exactly
    what the caller is looking for.
    """
    registry = StartedJobRegistry(queue_name, connection=connection)
    return list(registry.get_job_ids(cleanup=False))


def _text(value: bytes | str | None) -> str | None:
    if value is None:
        return None
    return value.decode() if isinstance(value, bytes) else value


def _rq_time(value: bytes | str | None) -> float | None:
    if not value:
        return None
    try:
        return utcparse(_text(value)).replace(tzinfo=timezone.utc).timestamp()
    except ValueError:
        return None
