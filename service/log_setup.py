"""Logging of the MoJu processes (``moju serve``, ``moju worker``): our loggers only.

RQ and uvicorn configure their own loggers; attaching a handler to the root logger too
would print their lines twice.
"""

from __future__ import annotations

import logging

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
_OUR_LOGGERS = ("service", "worker")


def configure_logging(level: int = logging.INFO) -> None:
    """Send the ``service`` and ``worker`` loggers to stderr (once per process)."""
    for name in _OUR_LOGGERS:
        logger = logging.getLogger(name)
        logger.setLevel(level)
        if not any(getattr(h, "_moju", False) for h in logger.handlers):
            handler = logging.StreamHandler()
            handler.setFormatter(logging.Formatter(LOG_FORMAT))
            handler._moju = True  # type: ignore[attr-defined]
            logger.addHandler(handler)
