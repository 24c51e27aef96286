"""The Redis client used by the API and the workers."""

from __future__ import annotations

from redis import Redis
from redis.asyncio import Redis as AsyncRedis
from redis.asyncio.retry import Retry as AsyncRetry
from redis.backoff import ExponentialBackoff
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.retry import Retry

#: A command that meets a broken connection is sent again this many times, on a fresh
#: connection: after a Redis restart every pooled connection is broken once, and without a
#: retry each would fail one request. A Redis that is down still fails fast (about 0.3 s).
RECONNECT_RETRIES = 2


def _backoff() -> ExponentialBackoff:
    return ExponentialBackoff(cap=0.25, base=0.05)


def connect_redis(url: str) -> Redis:
    """A Redis client returning bytes (RQ pickles job data, so no ``decode_responses``).

    The socket timeout is generous because a worker's blocking dequeue and a slow Redis
    under load must not be mistaken for a dead server.
    """
    return Redis.from_url(
        url,
        socket_connect_timeout=5,
        socket_timeout=30,
        health_check_interval=30,
        retry=Retry(_backoff(), RECONNECT_RETRIES, supported_errors=(RedisConnectionError,)),
    )


def connect_redis_async(url: str) -> AsyncRedis:
    """The asyncio twin of :func:`connect_redis`, for the API's event loop."""
    return AsyncRedis.from_url(
        url,
        socket_connect_timeout=5,
        socket_timeout=30,
        health_check_interval=30,
        retry=AsyncRetry(_backoff(), RECONNECT_RETRIES, supported_errors=(RedisConnectionError,)),
    )
