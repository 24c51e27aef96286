"""Liveness and readiness probes."""

from __future__ import annotations

from fastapi import APIRouter
from redis.exceptions import RedisError

from service import queueing
from service.deps import ServicesDep
from service.errors import NotReady
from service.schemas import ErrorBody, Health

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
    summary="Readiness: Redis reachable and a worker registered",
    description=(
        "200 when Redis answers and at least one worker listens on the job queue; 503 with "
        "the reason otherwise (jobs would be accepted but never run).\n\n"
        "    curl http://127.0.0.1:8000/readyz"
    ),
    response_model=Health,
    responses={503: {"model": ErrorBody, "description": "Not ready; the detail says why."}},
)
def ready(services: ServicesDep) -> Health:
    """Redis answers and a worker is registered on the queue."""
    try:
        services.redis.ping()
        workers = queueing.count_workers(services.redis, services.settings)
    except RedisError as exc:
        raise NotReady(f"Redis is unreachable ({type(exc).__name__}: {exc})") from None
    if workers == 0:
        raise NotReady(
            f"no worker is registered on queue {services.settings.queue_name!r}: start one "
            "with `moju worker` (same MOJU_REDIS_URL, MOJU_DATA_DIR and MOJU_QUEUE_NAME)"
        )
    return Health(workers=workers)
