"""Fixtures shared by every test package: a throwaway Redis (see tests/redis_server.py)."""

from redis_server import redis_server, redis_url  # noqa: F401 - fixtures, used by name
