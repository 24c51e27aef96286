"""The API under uvicorn, with the slow-client limits of :mod:`service.slow_clients`.

``python -m service.uvicorn_server --host 127.0.0.1 --port 8000`` is what ``moju serve``
runs; it is ``uvicorn --factory service.app:create_app`` plus a header timeout
(``MOJU_HEADER_TIMEOUT``), a minimum body rate (``MOJU_MIN_BODY_RATE`` after
``MOJU_BODY_RATE_GRACE``) and an idle timeout between requests (``MOJU_IDLE_TIMEOUT``).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import uvicorn

from service.settings import Settings, get_settings
from service.slow_clients import guarded_protocol


def uvicorn_config(
    settings: Settings,
    app: Any = "service.app:create_app",
    *,
    host: str = "127.0.0.1",
    port: int = 8000,
    **options: Any,
) -> uvicorn.Config:
    """A ``uvicorn.Config`` serving ``app`` (by default the factory) with the limits of
    ``settings`` on slow and idle clients."""
    if isinstance(app, str):
        options.setdefault("factory", True)
    return uvicorn.Config(
        app,
        host=host,
        port=port,
        http=guarded_protocol(
            settings.header_timeout, settings.min_body_rate, settings.body_rate_grace
        ),
        timeout_keep_alive=settings.idle_timeout,
        **options,
    )


def main(argv: Sequence[str] | None = None) -> None:
    """Serve the API until stopped (SIGINT or SIGTERM)."""
    parser = argparse.ArgumentParser(prog="python -m service.uvicorn_server")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--log-level", default="info")
    parser.add_argument(
        "--timeout-graceful-shutdown",
        type=int,
        default=3,
        help="seconds open requests get to end when stopping",
    )
    arguments = parser.parse_args(argv)
    config = uvicorn_config(
        get_settings(),
        host=arguments.host,
        port=arguments.port,
        log_level=arguments.log_level,
        timeout_graceful_shutdown=arguments.timeout_graceful_shutdown,
    )
    uvicorn.Server(config).run()


if __name__ == "__main__":
    main()
