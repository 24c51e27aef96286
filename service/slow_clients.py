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

Three things keep thousands of such clients cheap for everyone else. A request with a body
reaches the app only once 64 KiB of the body (or all of it) has arrived, so a trickling client
costs a parked future, not a request coroutine, and is dropped without unwinding one (a client
that waits for ``100 Continue`` goes through at once). Small pieces of a body are
handed to the app together, at most every :data:`COALESCE_SECONDS` (a full 64 KiB buffer, the
body's end or a disconnect go at once): a client trickling a byte at a time would otherwise
wake its request's whole coroutine stack for every byte. And slow bodies are dropped at most
:data:`DROPS_PER_TICK` per :data:`DROP_TICK_SECONDS`: unwinding a request in the app costs a
millisecond or so, and thousands of them due at the same moment would hold the event loop
for seconds; the rest are dropped a tick later.
"""

from __future__ import annotations

import asyncio
import json
import logging
import random
from typing import Any

import h11
from uvicorn.protocols.http.flow_control import HIGH_WATER_LIMIT
from uvicorn.protocols.http.h11_impl import H11Protocol, RequestResponseCycle

logger = logging.getLogger(__name__)

#: Seconds added to each body-rate deadline, so that a check that finds the rate exactly met
#: does not fire again at once.
_RATE_SLACK = 1.0
#: Longest wait before body bytes that arrived in small pieces are handed to the app.
COALESCE_SECONDS = 2.0
#: Slow bodies dropped at most this many per tick; the others wait for a later tick.
DROPS_PER_TICK = 50
DROP_TICK_SECONDS = 0.1


class _DropBudget:
    """How many slow bodies may still be dropped in the current tick (one per event loop)."""

    def __init__(self) -> None:
        self.tick = -1
        self.used = 0

    def take(self, now: float) -> bool:
        tick = int(now / DROP_TICK_SECONDS)
        if tick != self.tick:
            self.tick, self.used = tick, 0
        if self.used >= DROPS_PER_TICK:
            return False
        self.used += 1
        return True


_budgets: dict[asyncio.AbstractEventLoop, _DropBudget] = {}


def _budget(loop: asyncio.AbstractEventLoop) -> _DropBudget:
    budget = _budgets.get(loop)
    if budget is None:
        for old in [old for old in _budgets if old.is_closed()]:
            del _budgets[old]
        budget = _budgets[loop] = _DropBudget()
    return budget


class _CoalescingEvent(asyncio.Event):
    """The cycle's "message waiting" event, set for small body pieces only after a pause.

    uvicorn sets it for every piece of body it receives; here a piece smaller than the flow
    control's buffer wakes the app after :data:`COALESCE_SECONDS` at the latest, together
    with whatever else arrived meanwhile. The end of the body, a disconnect, a finished
    answer or a full buffer wake it at once.
    """

    def __init__(self, cycle: RequestResponseCycle, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__()
        self._cycle = cycle
        self._loop = loop
        self._pending: asyncio.TimerHandle | None = None

    def set(self) -> None:
        cycle = self._cycle
        small = len(cycle.body) < HIGH_WATER_LIMIT
        if small and cycle.more_body and not cycle.disconnected and not cycle.response_complete:
            if self._pending is None and not self.is_set():
                self._pending = self._loop.call_later(COALESCE_SECONDS, self._set_now)
            return
        self._set_now()

    def _set_now(self) -> None:
        if self._pending is not None:
            self._pending.cancel()
            self._pending = None
        super().set()


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
        self._inner_app = self.app
        self.app = self._gated_app
        super().connection_made(transport)
        self._await_headers()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_guard()
        self._open_gate(False)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._body_started is not None:
            self._body_bytes += len(data)
        super().data_received(data)
        cycle = self.cycle
        if cycle is not None and (len(cycle.body) >= HIGH_WATER_LIMIT or not cycle.more_body):
            self._open_gate(True)
        if self._body_started is not None and self.conn.their_state is not h11.SEND_BODY:
            self._body_started = None  # the body is complete
            self._cancel_guard()

    def handle_events(self) -> None:
        cycle = self.cycle
        super().handle_events()
        cycle = self.cycle if self.cycle is not cycle else None
        if cycle is not None:  # a request's headers arrived
            if cycle.more_body and not cycle.message_event.is_set():
                cycle.message_event = _CoalescingEvent(cycle, self.loop)
            self._cancel_guard()
            if self.conn.their_state is h11.SEND_BODY:
                self._start_body_clock()
                small = len(cycle.body) < HIGH_WATER_LIMIT
                # A client waiting for "100 Continue" sends its body only once the app reads.
                if small and cycle.more_body and not cycle.waiting_for_100_continue:
                    cycle.moju_gate = self.loop.create_future()  # type: ignore[attr-defined]

    # The gate: the app starts on a request with a body once 64 KiB of it (or all of it) is
    # here. A client that trickles its body costs no app coroutine, and dropping it none.

    async def _gated_app(self, scope: Any, receive: Any, send: Any) -> None:
        gate = getattr(getattr(receive, "__self__", None), "moju_gate", None)
        if gate is not None and not await gate:
            return  # dropped (slow) or gone before its body was worth reading
        await self._inner_app(scope, receive, send)

    def _open_gate(self, go_on: bool) -> None:
        gate = getattr(self.cycle, "moju_gate", None)
        if gate is not None and not gate.done():
            gate.set_result(go_on)

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
        if not _budget(self.loop).take(self.loop.time()):  # enough dropped for now
            delay = DROP_TICK_SECONDS * (1 + random.random())
            self._guard = self.loop.call_later(delay, self._check_body_rate)
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
        self._open_gate(False)  # a request still at its gate never reaches the app
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
