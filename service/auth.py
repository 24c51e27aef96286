"""Optional API keys: who may call ``/v1``, and whose jobs a caller may see.

Keys come from ``MOJU_API_KEYS`` (comma separated) and ``MOJU_API_KEYS_FILE`` (one per line,
``#`` starts a comment). Each entry is either the key itself or ``sha256:<hex digest>`` of the
key, so that a deployment can keep only digests in its configuration. Either way the server
keeps nothing but the digests in memory: a request's key is hashed and looked up.

A caller is identified by its key's *owner id*, ``key-`` and the first 16 hex digits of the
key's SHA-256 digest. Jobs are stored with the owner id of the key that submitted them; log
lines name owner ids, never keys. Without any key configured, every caller is the anonymous
owner (the empty string) and sees every job.

Keys are sent as ``Authorization: Bearer <key>`` or ``X-API-Key: <key>``; a key is never
accepted in the URL, where proxies and access logs would record it.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from service.settings import Settings

#: Owner id of every caller when the server has no API keys.
ANONYMOUS = ""
#: Shortest key accepted in the configuration (in clear): shorter ones are guessable.
MIN_KEY_LENGTH = 16

_DIGEST = re.compile(r"^sha256:([0-9a-fA-F]{64})$")
_HOW_TO_SEND = "send it as 'Authorization: Bearer <key>' or as 'X-API-Key: <key>'"


def key_digest(key: str) -> str:
    """SHA-256 hex digest of a key (what the configuration may hold instead of the key)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def owner_id(digest: str) -> str:
    """The owner id of the key with this digest: safe to log and to store with jobs."""
    return f"key-{digest[:16]}"


def _entries(text: str, *, separator: str | None) -> list[str]:
    lines = text.split(separator) if separator else text.splitlines()
    found = []
    for line in lines:
        entry = line.split("#", 1)[0].strip() if separator is None else line.strip()
        if entry:
            found.append(entry)
    return found


def _digest_of_entry(entry: str, where: str, position: int) -> str:
    match = _DIGEST.match(entry)
    if match:
        return match.group(1).lower()
    if entry.lower().startswith("sha256:"):
        raise ValueError(
            f"entry {position} of {where} starts with 'sha256:' but is not followed by 64 hex "
            "digits"
        )
    if len(entry) < MIN_KEY_LENGTH or any(c.isspace() for c in entry):
        # The message must not repeat the key.
        raise ValueError(
            f"entry {position} of {where} is not a usable API key: keys need at least "
            f"{MIN_KEY_LENGTH} characters and no spaces (make one with `moju api-key`)"
        )
    return key_digest(entry)


@dataclass(frozen=True)
class ApiKeys:
    """The digests of the configured keys; empty when the server needs no key."""

    digests: frozenset[str]

    @classmethod
    def from_entries(cls, entries: Iterable[tuple[str, str]]) -> ApiKeys:
        """Keys from ``(entry, where)`` pairs; raises ValueError on an unusable entry."""
        digests = set()
        for position, (entry, where) in enumerate(entries, start=1):
            digests.add(_digest_of_entry(entry, where, position))
        return cls(frozenset(digests))

    @classmethod
    def from_settings(cls, settings: Settings) -> ApiKeys:
        """Keys of ``MOJU_API_KEYS`` and ``MOJU_API_KEYS_FILE``."""
        entries: list[tuple[str, str]] = []
        if settings.api_keys is not None:
            text = settings.api_keys.get_secret_value()
            entries += [(e, "MOJU_API_KEYS") for e in _entries(text, separator=",")]
        if settings.api_keys_file is not None:
            path = Path(settings.api_keys_file)
            try:
                text = path.read_text(encoding="utf-8")
            except OSError as exc:
                raise ValueError(
                    f"cannot read MOJU_API_KEYS_FILE {str(path)!r}: {exc.strerror}"
                ) from None
            entries += [(e, "MOJU_API_KEYS_FILE") for e in _entries(text, separator=None)]
        keys = cls.from_entries(entries)
        configured = settings.api_keys is not None or settings.api_keys_file is not None
        if configured and not keys.enabled:
            raise ValueError(
                "MOJU_API_KEYS / MOJU_API_KEYS_FILE are set but hold no key; remove them to run "
                "without keys, or add a key"
            )
        return keys

    @property
    def enabled(self) -> bool:
        """True when callers must present a key."""
        return bool(self.digests)

    def owner_of(self, key: str) -> str | None:
        """The owner id of a presented key, or None when it is not one of ours."""
        digest = key_digest(key)
        return owner_id(digest) if digest in self.digests else None


class AuthenticationFailed(Exception):
    """No key, or an unknown key, on a route that needs one (HTTP 401)."""

    def __init__(self, message: str) -> None:
        super().__init__(message)


def presented_key(authorization: str | None, api_key_header: str | None) -> str | None:
    """The key a request carries (``Authorization: Bearer`` or ``X-API-Key``), if any."""
    if api_key_header:
        return api_key_header.strip()
    if authorization:
        scheme, _, value = authorization.strip().partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return value.strip()
    return None


def authenticate(keys: ApiKeys, authorization: str | None, api_key_header: str | None) -> str:
    """The caller's owner id; raises :class:`AuthenticationFailed` when a key is required."""
    if not keys.enabled:
        return ANONYMOUS
    key = presented_key(authorization, api_key_header)
    if key is None:
        if authorization and not api_key_header:
            raise AuthenticationFailed(
                "the Authorization header is not 'Bearer <key>'; this server needs an API "
                f"key: {_HOW_TO_SEND}"
            )
        raise AuthenticationFailed(f"this server needs an API key: {_HOW_TO_SEND}")
    owner = keys.owner_of(key)
    if owner is None:
        raise AuthenticationFailed(
            "the API key is not valid on this server (check for a typo or ask the operator "
            "for a key)"
        )
    return owner
