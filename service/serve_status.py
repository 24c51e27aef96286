"""What ``moju serve`` has down right now, told to the API (``/readyz``) through Redis.

The supervisor of ``moju serve`` knows when one of its processes died and when it will be
started again; the API does not (a killed worker stays registered in RQ for minutes). The
supervisor therefore keeps a short list of sentences in a Redis key with a short TTL, so that a
supervisor that itself went away leaves no stale entry behind, and ``/readyz`` answers 503 with
those sentences while the list is not empty.
"""

from __future__ import annotations

import json

from redis import Redis

#: Seconds the published list stays valid; the supervisor renews it about twice a second.
STATUS_TTL_SECONDS = 5


def status_key(queue_name: str) -> str:
    """The Redis key of the list, one per job queue (``moju:serve:down:<queue>``)."""
    return f"moju:serve:down:{queue_name}"


def publish_down(connection: Redis, queue_name: str, down: list[str]) -> None:
    """Record the processes that are down (an empty list clears the record)."""
    key = status_key(queue_name)
    if down:
        connection.set(key, json.dumps(down), ex=STATUS_TTL_SECONDS)
    else:
        connection.delete(key)


def read_down(connection: Redis, queue_name: str) -> list[str]:
    """The sentences last published by :func:`publish_down` (empty when all is up)."""
    raw = connection.get(status_key(queue_name))
    if not raw:
        return []
    try:
        value = json.loads(raw)
    except ValueError:
        return []
    return [str(item) for item in value] if isinstance(value, list) else []
