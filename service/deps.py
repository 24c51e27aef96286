"""FastAPI dependencies as typed aliases: the process-wide services, the caller, the job id."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Annotated
from uuid import UUID

import anyio
from fastapi import Depends, Path, Request
from fastapi.security import APIKeyHeader, HTTPBearer
from redis import Redis

from service.auth import ApiKeys, AuthenticationFailed, authenticate
from service.errors import InvalidJobId
from service.job_store import JobStore
from service.settings import Settings
from service.storage import Storage

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Services:
    """What every request handler may need; built once by the app's lifespan."""

    settings: Settings
    redis: Redis
    store: JobStore
    storage: Storage
    keys: ApiKeys
    #: Bounds the upload checks running at once (MOJU_UPLOAD_CHECKS).
    upload_checks: anyio.CapacityLimiter


# The dependencies below are ``async def`` although they never await: FastAPI runs a plain
# ``def`` dependency in its thread pool, and two thread hops per request cost more CPU than
# the rest of a status request together.


async def get_services(request: Request) -> Services:
    """The services of the app handling ``request``."""
    return request.app.state.services


async def parse_job_id(
    job_id: Annotated[
        str,
        Path(
            description="Job id (UUID4) returned by POST /v1/jobs.",
            examples=["0b7e9f6c-3a51-4f0e-9d7c-2c1e8a4b5d60"],
        ),
    ],
) -> UUID:
    """The job id of the path as a UUID; anything else is a job that does not exist (404)."""
    try:
        parsed = UUID(job_id)
    except ValueError:
        raise InvalidJobId(job_id) from None
    # Only the canonical spelling names a job, so one job never has two URLs.
    if parsed.version != 4 or str(parsed) != job_id:
        raise InvalidJobId(job_id)
    return parsed


# Declared for the OpenAPI document (its security schemes); the key is read from the headers
# by get_caller, which also tells a malformed Authorization header from a missing one.
_BEARER = HTTPBearer(
    auto_error=False,
    description="An API key of this server, as `Authorization: Bearer <key>` (when it has keys).",
)
_API_KEY_HEADER = APIKeyHeader(
    name="X-API-Key",
    auto_error=False,
    description="An API key of this server, as `X-API-Key: <key>` (when it has keys).",
)


async def get_caller(
    request: Request,
    _bearer: Annotated[object, Depends(_BEARER)],
    _header: Annotated[object, Depends(_API_KEY_HEADER)],
) -> str:
    """The caller's owner id (see :mod:`service.auth`): "" when the server has no keys.

    Raises :class:`service.auth.AuthenticationFailed` (HTTP 401) when the server has keys and
    the request carries none of them.
    """
    keys: ApiKeys = request.app.state.services.keys
    if not keys.enabled:
        return ""
    headers = request.headers
    try:
        return authenticate(keys, headers.get("authorization"), headers.get("x-api-key"))
    except AuthenticationFailed:
        client = request.client.host if request.client else "unknown client"
        # Never the key itself: only that one was refused, and from where.
        logger.warning("refused %s %s from %s: no valid API key",
                       request.method, request.url.path, client)  # fmt: skip
        raise


ServicesDep = Annotated[Services, Depends(get_services)]
JobId = Annotated[UUID, Depends(parse_job_id)]
#: The caller's owner id; every /v1 route depends on it, so it also enforces the keys.
Caller = Annotated[str, Depends(get_caller)]
