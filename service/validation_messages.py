"""Turn pydantic validation errors into one readable sentence for ``{"detail": ...}``."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from moju_core.params import SolverParams

_MAX_SHOWN_ERRORS = 5
_LOCATION_KINDS = {"query": "query parameter", "path": "path parameter", "header": "header"}


#: Longest field or parameter name shown back (a client may send a name of any length).
_MAX_NAME = 60


def shorten(text: str, limit: int = _MAX_NAME) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was when cut."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


def _path(location: Sequence[str | int]) -> str:
    text = ""
    for part in location:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return shorten(text)


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def describe_error(error: Mapping[str, Any], *, parameters_at: str | None = None) -> str:
    """One pydantic error as a phrase.

    Parameters
    ----------
    error : mapping
        An item of ``ValidationError.errors()``.
    parameters_at : str or None
        Name of the location holding solver parameters (``"params"`` in a request body), or
        None when ``error`` comes from validating :class:`SolverParams` directly.
    """
    location = list(error.get("loc", ()))
    if location and location[0] == "body":
        location = location[1:]
    kind = None
    if location and location[0] in _LOCATION_KINDS:
        kind = _LOCATION_KINDS[location.pop(0)]
    is_parameter = parameters_at is None or (location[:1] == [parameters_at] and len(location) > 1)
    if parameters_at is not None and is_parameter:
        location = location[1:]
    name = _path(location)
    if error.get("type") == "extra_forbidden":
        if is_parameter and kind is None:
            return f"unknown parameter {name!r}"
        return f"unexpected field {name!r}"
    message = str(error.get("msg", "is invalid"))
    got = f" (got {_shown(error['input'])})" if "input" in error and location else ""
    if kind is not None:
        return f"{kind} {name!r}: {message}{got}"
    if is_parameter:
        return f"parameter {name!r}: {message}{got}"
    return f"{name or 'body'}: {message}{got}"


def describe_errors(errors: Iterable[Mapping[str, Any]], *, parameters_at: str | None) -> str:
    """Several pydantic errors as one sentence, with the list of known parameters if needed."""
    errors = list(errors)
    phrases = [describe_error(e, parameters_at=parameters_at) for e in errors]
    text = "; ".join(phrases[:_MAX_SHOWN_ERRORS])
    if len(phrases) > _MAX_SHOWN_ERRORS:
        text += f"; and {len(phrases) - _MAX_SHOWN_ERRORS} more"
    if any(phrase.startswith("unknown parameter") for phrase in phrases):
        text += "; known parameters: " + ", ".join(SolverParams.model_fields)
    return text
