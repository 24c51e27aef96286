"""The FastAPI application: ``create_app()`` wires settings, Redis, storage and the routers.

Run it with ``uvicorn --factory service.app:create_app`` (``moju serve`` does that for you).
"""

from __future__ import annotations

import contextlib
import gc
import logging
from collections.abc import AsyncIterator
from typing import Any

import anyio
import anyio.to_thread
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse, Response
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from moju_core import __version__
from service.auth import ApiKeys, AuthenticationFailed
from service.connection import connect_redis, connect_redis_async
from service.deps import Services
from service.errors import ServiceError
from service.job_store import JobStore
from service.log_setup import configure_logging
from service.retention import sweep
from service.routes import api_docs, downloads, health, jobs, viewer
from service.settings import Settings, get_settings
from service.storage import JobFilesMissing, LocalStorage
from service.validation_messages import describe_errors, shorten
from service.watchdog import Watchdog

logger = logging.getLogger(__name__)

#: The garbage collector's thresholds in the API (Python's default: 700, 10, 10). Thousands
#: of open connections are hundreds of thousands of live objects; at the default a full
#: collection came every second or two while they closed, each holding the event loop for
#: 0.3-0.4 s. Collecting young objects less often costs a few MB of garbage kept a little
#: longer.
GC_THRESHOLDS = (20_000, 20, 20)

#: Retry-After of the 503 answered while Redis is unreachable.
REDIS_RETRY_AFTER_SECONDS = 5

DESCRIPTION = """\
Dense non-rigid structure from motion (MoJu, Kumar CVPR 2019) as a job service.

Submit dense 2D tracks with `POST /v1/jobs`, follow the job with `GET /v1/jobs/{id}` or its
server-sent events, then download per-frame 3D shapes and camera rotations (HDF5, npz, PLY).
Every error answers `{"detail": "<what is wrong and what to do>"}`.

When the server has API keys, every `/v1` route needs one, as `Authorization: Bearer <key>`
or `X-API-Key: <key>`; a caller sees only the jobs submitted with its own key.
"""


def _error(status_code: int, detail: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": detail}, status_code=status_code, headers=headers)


def _install_error_handlers(app: FastAPI) -> None:
    """Map every error to ``{"detail": "..."}`` with one sentence (in one place)."""

    @app.exception_handler(ServiceError)
    async def service_error(request: Request, exc: ServiceError) -> JSONResponse:
        return _error(exc.status_code, str(exc), exc.headers or None)

    @app.exception_handler(AuthenticationFailed)
    async def unauthenticated(request: Request, exc: AuthenticationFailed) -> JSONResponse:
        return _error(401, str(exc), {"WWW-Authenticate": "Bearer"})

    @app.exception_handler(JobFilesMissing)
    async def files_missing(request: Request, exc: JobFilesMissing) -> JSONResponse:
        return _error(
            404, f"the files of job {exc.job_id} are gone (deleted, or past their retention)"
        )

    @app.exception_handler(ClientDisconnect)
    async def client_gone(request: Request, exc: ClientDisconnect) -> Response:
        # Nobody is left to read an answer; one line instead of a traceback per aborted upload.
        logger.info(
            "client went away during %s %s; request dropped", request.method, request.url.path
        )
        return Response(status_code=400)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail
        if exc.status_code == 404 and detail == "Not Found":
            path = shorten(request.url.path, 200)  # a path may be tens of kB long
            detail = f"no endpoint {shorten(request.method, 20)} {path}; the API is listed at /docs"
        return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _error(422, describe_errors(exc.errors(), parameters_at="params"))

    async def redis_down(request: Request, exc: Exception) -> JSONResponse:
        logger.error("Redis unreachable: %s", exc)
        return _error(
            503,
            "the job database (Redis) is unreachable; try again shortly",
            {"Retry-After": str(REDIS_RETRY_AFTER_SECONDS)},
        )

    app.add_exception_handler(RedisConnectionError, redis_down)
    app.add_exception_handler(RedisTimeoutError, redis_down)


def _openapi_document(app: FastAPI) -> dict[str, Any]:
    """The OpenAPI document, with the models the hand-written request body refers to."""
    document = get_openapi(
        title=app.title,
        version=app.version,
        description=app.description,
        routes=app.routes,
        tags=app.openapi_tags,
    )
    schemas = document.setdefault("components", {}).setdefault("schemas", {})
    # Request validation errors answer {"detail": "<sentence>"} (see _install_error_handlers),
    # not FastAPI's default list of errors: document what is really sent.
    for operations in document["paths"].values():
        for operation in operations.values():
            # API keys are optional (MOJU_API_KEYS): an empty requirement says so.
            if operation.get("security") and {} not in operation["security"]:
                operation["security"].append({})
            invalid = operation.get("responses", {}).get("422")
            if invalid is None:
                continue
            content = invalid.setdefault("content", {}).setdefault("application/json", {})
            content["schema"] = {"$ref": "#/components/schemas/ErrorBody"}
            if invalid.get("description") == "Validation Error":
                invalid["description"] = "A parameter is invalid (the message says which)."
    for unused in ("HTTPValidationError", "ValidationError"):
        schemas.pop(unused, None)
    for model in jobs.EXTRA_SCHEMAS:
        schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
        schemas.update(schema.pop("$defs", {}))
        schemas.setdefault(model.__name__, schema)
    document["components"]["schemas"] = dict(sorted(schemas.items()))
    return document


async def _watch_periodically(watchdog: Watchdog, interval: float) -> None:
    """Look for jobs whose worker is gone every ``interval`` seconds (MOJU_HEARTBEAT_INTERVAL)."""
    while True:
        try:
            await anyio.to_thread.run_sync(watchdog.sweep)
        except Exception:  # e.g. Redis restarting: the next look will do
            logger.warning("looking for jobs of lost workers failed", exc_info=True)
        await anyio.sleep(interval)


async def _sweep_periodically(services: Services) -> None:
    interval = services.settings.cleanup_interval
    while True:
        try:
            await anyio.to_thread.run_sync(sweep, services.store, services.storage)
        except Exception:  # a failed sweep must not take the API down; try again later
            logger.exception("sweeping expired job files failed")
        await anyio.sleep(interval)


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the API application.

    Parameters
    ----------
    settings : Settings, optional
        Configuration; by default read from ``MOJU_*`` environment variables.
    """
    settings = settings or get_settings()
    configure_logging()  # the API's own lines (job queued, lost workers, refused keys)
    keys = ApiKeys.from_settings(settings)  # a bad key file stops the start, not a request

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        redis = connect_redis(settings.require_redis_url())
        async_redis = connect_redis_async(settings.require_redis_url())
        services = Services(
            settings=settings,
            redis=redis,
            store=JobStore(
                redis,
                retention_seconds=settings.result_ttl,
                async_connection=async_redis,
                lease_seconds=settings.heartbeat_ttl,
            ),
            storage=LocalStorage(settings.data_dir),
            keys=keys,
            upload_checks=anyio.CapacityLimiter(settings.upload_checks),
        )
        watchdog = Watchdog(redis, services.store, services.storage, settings)
        app.state.services = services
        # Everything the start allocated (modules, the app, its routes: most of the heap)
        # lives as long as the process; kept out of the garbage collector's full passes,
        # which would otherwise scan it all each time and hold the event loop for a few
        # hundred milliseconds while thousands of connections come and go.
        gc.collect()
        gc.freeze()
        gc.set_threshold(*GC_THRESHOLDS)
        if keys.enabled:
            logger.info("API keys required on /v1 (%d key(s) configured)", len(keys.digests))
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(_watch_periodically, watchdog, settings.heartbeat_interval)
            if settings.cleanup_interval > 0:
                tasks.start_soon(_sweep_periodically, services)
            try:
                yield
            finally:
                tasks.cancel_scope.cancel()
        redis.close()
        await async_redis.aclose()

    app = FastAPI(
        title="MoJu reconstruction service",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        # /docs is served by service.routes.api_docs from local files; FastAPI's own pages
        # load their scripts from a CDN.
        docs_url=None,
        redoc_url=None,
        openapi_tags=[
            {"name": "jobs", "description": "Submit, follow, list and delete jobs."},
            {"name": "downloads", "description": "Results of finished jobs."},
            {"name": "health", "description": "Probes for orchestrators."},
        ],
    )
    _install_error_handlers(app)
    if settings.cors_origin_list:
        # Off by default: the web page is served by the API itself and needs no CORS.
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origin_list,
            allow_methods=["GET", "POST", "DELETE"],
            allow_headers=["Authorization", "X-API-Key", "Content-Type"],
            expose_headers=["Location", "Retry-After"],
            max_age=600,
        )
    app.include_router(jobs.router)
    app.include_router(downloads.router)
    app.include_router(health.router)
    app.include_router(viewer.router)
    app.include_router(api_docs.router)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = _openapi_document(app)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    return app
