"""Logging of the MoJu processes (``moju serve``, ``moju worker``): our loggers only.

RQ and uvicorn configure their own loggers; attaching a handler to the root logger too
would print their lines twice.
"""

from __future__ import annotations

import logging
import re

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
_OUR_LOGGERS = ("service", "worker")
#: Longest request path written to the access log (a client may send tens of kB).
MAX_LOGGED_PATH = 300
#: ``name=value`` pairs (query parameters) whose values are credentials: written as "***".
_SECRET_PAIR = re.compile(
    r"(?i)([^\s=&;?'\"]*(?:key|token|secret|passw|auth)[^\s=&;?'\"]*=)[^\s&;'\"]*"
)
#: uvicorn's loggers that may write a request's path or query (access log, errors, and at
#: trace level the ASGI messages with the scope).
_UVICORN_LOGGERS = ("uvicorn.access", "uvicorn.error", "uvicorn.asgi")


def redact(text: str) -> str:
    """``text`` with the values of credential-like ``name=value`` pairs replaced by ***."""
    return _SECRET_PAIR.sub(r"\1***", text)


def redact_path(path: str) -> str:
    """A request path (with its query) fit for a log: credentials hidden, length bounded."""
    path = redact(path)
    if len(path) > MAX_LOGGED_PATH:
        path = f"{path[:MAX_LOGGED_PATH]}... ({len(path)} characters)"
    return path


class LogRedaction(logging.Filter):
    """Hides credentials sent in a query (``?api_key=...``) in uvicorn's log lines, and
    bounds the length of the path in its access log.

    uvicorn logs ``(client, method, path with query, HTTP version, status)`` for each request;
    a key sent as a query parameter would otherwise be written verbatim.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if record.name == "uvicorn.access" and isinstance(args, tuple) and len(args) >= 3:
            record.args = (*args[:2], redact_path(str(args[2])), *args[3:])
            return True
        message = record.getMessage()
        cleaned = redact(message)
        if cleaned != message:
            record.msg, record.args = cleaned, None
        return True


def configure_logging(level: int = logging.INFO) -> None:
    """Send the ``service`` and ``worker`` loggers to stderr (once per process), and hide
    credentials and overlong paths in uvicorn's access log (a filter on its logger, which
    uvicorn's own logging configuration leaves in place)."""
    for name in _OUR_LOGGERS:
        logger = logging.getLogger(name)
        logger.setLevel(level)
        if not any(getattr(h, "_moju", False) for h in logger.handlers):
            handler = logging.StreamHandler()
            handler.setFormatter(logging.Formatter(LOG_FORMAT))
            handler._moju = True  # type: ignore[attr-defined]
            logger.addHandler(handler)
    for name in _UVICORN_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, LogRedaction) for f in logger.filters):
            logger.addFilter(LogRedaction())
