"""Liveness and readiness probes."""

from __future__ import annotations

from fastapi import APIRouter
from redis.exceptions import RedisError

from service import queueing
from service.deps import ServicesDep
from service.errors import NotReady
from service.schemas import ErrorBody, Health
from service.serve_status import read_down

router = APIRouter(tags=["health"])


@router.get(
    "/healthz",
    operation_id="health",
    summary="Liveness: the API process is up",
    description="Answers 200 whenever the process serves requests; it checks nothing else.\n\n"
    "    curl http://127.0.0.1:8000/healthz",
    response_model=Health,
    response_model_exclude_none=True,
)
async def health() -> Health:
    """The process is up."""
    return Health()


@router.get(
    "/readyz",
    operation_id="ready",
    summary="Readiness: Redis reachable, a worker registered, nothing restarting",
    description=(
        "200 when Redis answers, at least one worker listens on the job queue and (under "
        "`moju serve`) none of its processes is down; 503 with the reason otherwise: Redis "
        "unreachable, no worker (jobs would be accepted but never run), or which process of "
        "`moju serve` died and when it will be started again.\n\n"
        "    curl http://127.0.0.1:8000/readyz"
    ),
    response_model=Health,
    responses={503: {"model": ErrorBody, "description": "Not ready; the detail says why."}},
)
def ready(services: ServicesDep) -> Health:
    """Redis answers, a worker is registered on the queue and nothing is restarting."""
    try:
        services.redis.ping()
        workers = queueing.count_workers(services.redis, services.settings)
        down = read_down(services.redis, services.settings.queue_name)
    except RedisError as exc:
        raise NotReady(f"Redis is unreachable ({type(exc).__name__}: {exc})") from None
    if down:
        raise NotReady(f"down under moju serve: {'; '.join(down)}")
    if workers == 0:
        raise NotReady(
            f"no worker is registered on queue {services.settings.queue_name!r}: start one "
            "with `moju worker` (same MOJU_REDIS_URL, MOJU_DATA_DIR and MOJU_QUEUE_NAME)"
        )
    return Health(workers=workers)
