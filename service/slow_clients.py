"""Slow and idle clients: a header timeout and a minimum body rate for uvicorn's HTTP/1.1.

uvicorn closes a connection that stays idle *between* requests (``timeout_keep_alive``,
``MOJU_IDLE_TIMEOUT``), but it waits forever for the headers of a request (a client that
connects and sends nothing, or a byte now and then) and for a body that trickles in. Each
such connection costs a socket and some memory, and a few thousand of them slow every other
request. :class:`GuardedH11Protocol` adds, per connection, one timer:

* **headers**: from the moment the client connects (or its previous answer ended), the
  request line and headers must be complete within ``header_timeout`` seconds
  (``MOJU_HEADER_TIMEOUT``); otherwise the connection is closed;
* **body**: once ``body_rate_grace`` seconds (``MOJU_BODY_RATE_GRACE``) have passed since
  the headers, the body must have arrived at ``min_body_rate`` bytes per second on average
  (``MOJU_MIN_BODY_RATE``); otherwise the request is answered 408 (when no answer has
  started) and the connection is closed. Time while the server itself is not reading (its
  flow control paused reading because the app is busy) does not count against the client.

The app's own ``MOJU_BODY_TIMEOUT`` (no byte at all for that long) still applies on top.
"""

from __future__ import annotations

import asyncio
import json
import logging

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

logger = logging.getLogger(__name__)

#: Seconds added to each body-rate deadline, so that a check that finds the rate exactly met
#: does not fire again at once.
_RATE_SLACK = 1.0


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a header timeout and a minimum body rate.

    Configure it through :func:`guarded_protocol` (class attributes, since uvicorn builds
    one protocol object per connection from its ``Config`` alone).
    """

    header_timeout: float = 20.0
    min_body_rate: float = 500.0
    body_rate_grace: float = 20.0

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        self._guard: asyncio.TimerHandle | None = None
        self._body_started: float | None = None
        self._body_bytes = 0
        super().connection_made(transport)
        self._await_headers()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_guard()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._body_started is not None:
            self._body_bytes += len(data)
        super().data_received(data)
        if self._body_started is not None and self.conn.their_state is not h11.SEND_BODY:
            self._body_started = None  # the body is complete
            self._cancel_guard()

    def handle_events(self) -> None:
        cycle = self.cycle
        super().handle_events()
        if self.cycle is not cycle and self.cycle is not None:  # a request's headers arrived
            self._cancel_guard()
            if self.conn.their_state is h11.SEND_BODY:
                self._start_body_clock()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing() and self.conn.their_state is not h11.SEND_BODY:
            self._await_headers()  # of the next request on this connection

    # The timers.

    def _cancel_guard(self) -> None:
        if self._guard is not None:
            self._guard.cancel()
            self._guard = None

    def _await_headers(self) -> None:
        self._cancel_guard()
        self._guard = self.loop.call_later(self.header_timeout, self._headers_too_slow)

    def _headers_too_slow(self) -> None:
        self._guard = None
        waiting = self.cycle is None or self.cycle.response_complete
        if waiting and not self.transport.is_closing():
            logger.info(
                "closed a connection from %s: no complete request headers within %g s "
                "(MOJU_HEADER_TIMEOUT)",
                _peer(self.client),
                self.header_timeout,
            )
            self.transport.close()

    def _start_body_clock(self) -> None:
        self._body_started = self.loop.time()
        self._body_bytes = 0
        self._schedule_rate_check()

    def _schedule_rate_check(self) -> None:
        if self.min_body_rate <= 0 or self._body_started is None:
            return
        due = self._body_started + max(
            self.body_rate_grace, self._body_bytes / self.min_body_rate + _RATE_SLACK
        )
        self._guard = self.loop.call_at(due, self._check_body_rate)

    def _check_body_rate(self) -> None:
        self._guard = None
        if self._body_started is None or self.transport.is_closing():
            return
        if self.conn.their_state is not h11.SEND_BODY:
            self._body_started = None
            return
        if self.flow.read_paused:  # the server is the slow side: measure again from now
            self._start_body_clock()
            return
        elapsed = self.loop.time() - self._body_started
        if self._body_bytes >= self.min_body_rate * elapsed:
            self._schedule_rate_check()
            return
        self._drop_slow_body(elapsed)

    def _drop_slow_body(self, elapsed: float) -> None:
        received = self._body_bytes
        logger.info(
            "dropped a request body from %s: %d bytes in %.0f s, under %g bytes/s "
            "(MOJU_MIN_BODY_RATE)",
            _peer(self.client),
            received,
            elapsed,
            self.min_body_rate,
        )
        cycle = self.cycle
        if cycle is not None and not cycle.response_started:
            detail = (
                f"the request body arrived at {received / max(elapsed, 1e-9):.0f} bytes/s "
                f"({received} bytes in {elapsed:.0f} s); this server needs at least "
                f"{self.min_body_rate:g} bytes/s (MOJU_MIN_BODY_RATE). Send the body without "
                "pausing, over a faster connection"
            )
            self._send_408(detail)
        if cycle is not None:
            # The app sees a client that went away; anything it sends now is dropped.
            cycle.disconnected = True
            cycle.message_event.set()
        self.transport.close()

    def _send_408(self, detail: str) -> None:
        body = json.dumps({"detail": detail}).encode()
        headers = [
            (b"content-type", b"application/json"),
            (b"content-length", str(len(body)).encode()),
            (b"connection", b"close"),
        ]
        try:
            output = self.conn.send(
                h11.Response(status_code=408, headers=headers, reason=b"Request Timeout")
            )
            output += self.conn.send(h11.Data(data=body))  # type: ignore[operator]
            output += self.conn.send(h11.EndOfMessage())  # type: ignore[operator]
        except h11.LocalProtocolError:  # h11 cannot answer in this state: just close
            return
        self.transport.write(output)  # type: ignore[arg-type]


def _peer(client: tuple[str, int] | None) -> str:
    return f"{client[0]}:{client[1]}" if client else "an unknown client"


def guarded_protocol(
    header_timeout: float, min_body_rate: float, body_rate_grace: float
) -> type[GuardedH11Protocol]:
    """A :class:`GuardedH11Protocol` class with these limits, for ``uvicorn.Config(http=...)``."""
    return type(
        "GuardedH11Protocol",
        (GuardedH11Protocol,),
        {
            "header_timeout": header_timeout,
            "min_body_rate": float(min_body_rate),
            "body_rate_grace": body_rate_grace,
        },
    )
