"""Transport-level limits for uvicorn's HTTP/1.1 protocol: per-IP connection caps and
a deadline for the request headers, below anything ASGI middleware can see.

uvicorn closes a keep-alive connection idle between requests after ``timeout_keep_alive``, but
until the *first* request's headers are complete nothing times out, and nothing counts
connections per client: an attack campaign held 20 200 half-open connections and exhausted
the file handles (slowloris). :func:`guarded_h11` returns uvicorn's h11 protocol class with:

- at most ``max_per_ip`` open connections per client address (a further one is closed at once,
  before a byte is read; a WebSocket's slot is handed to the rosbridge endpoint's own caps on
  upgrade);
- each request's headers due within ``header_timeout_s`` of the connection opening or of the
  previous response (then the connection is closed): a trickle of header bytes never expires
  uvicorn's own keep-alive timer, which every received byte resets.

Pass it as ``uvicorn.Config(http=guarded_h11(limits))``.
"""

from __future__ import annotations

import asyncio
import collections
from dataclasses import dataclass, field
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

DEFAULT_MAX_PER_IP = 256  # a browser opens ~6; scripts and tests a few dozen
DEFAULT_HEADER_TIMEOUT_S = 10.0  # Apache's RequestReadTimeout header=10-20 (mod_reqtimeout)
KEEP_ALIVE_S = 5  # idle time between requests (uvicorn's default, made explicit)


@dataclass
class ConnectionLimits:
    """The limits, and the live count of connections per client address."""

    max_per_ip: int = DEFAULT_MAX_PER_IP
    header_timeout_s: float = DEFAULT_HEADER_TIMEOUT_S
    open: collections.Counter[str] = field(default_factory=collections.Counter)
    refused: int = 0
    timed_out: int = 0


def guarded_h11(limits: ConnectionLimits) -> type[H11Protocol]:
    """uvicorn's h11 protocol class with ``limits`` applied (see the module docstring)."""

    class GuardedH11Protocol(H11Protocol):
        _guard_ip: str | None = None
        _header_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            ip = self.client[0] if self.client else "?"
            if limits.open[ip] >= limits.max_per_ip:
                limits.refused += 1
                transport.abort()
                return
            limits.open[ip] += 1
            self._guard_ip = ip
            self._arm_header_timer()

        def _headers_too_slow(self) -> None:
            self._header_timer = None
            limits.timed_out += 1
            self.transport.abort()

        def _cancel_header_timer(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _release(self) -> None:
            self._cancel_header_timer()
            ip, self._guard_ip = self._guard_ip, None
            if ip is not None:
                limits.open[ip] -= 1
                if limits.open[ip] <= 0:
                    del limits.open[ip]

        def _arm_header_timer(self) -> None:
            self._cancel_header_timer()
            self._header_timer = self.loop.call_later(
                limits.header_timeout_s, self._headers_too_slow
            )

        def handle_events(self) -> None:
            super().handle_events()
            # h11 leaves IDLE once a request's headers are complete: the deadline is met.
            if self._header_timer is not None and self.conn.their_state is not h11.IDLE:
                self._cancel_header_timer()

        def on_response_complete(self) -> None:
            # The next request's headers get their own deadline (uvicorn's keep-alive timer is
            # reset by every byte received, so a trickle of header bytes would never expire).
            if self._guard_ip is not None and not self.transport.is_closing():
                self._arm_header_timer()
            super().on_response_complete()

        def handle_websocket_upgrade(self, event: Any) -> None:
            self._release()
            super().handle_websocket_upgrade(event)

        def connection_lost(self, exc: Exception | None) -> None:
            self._release()
            super().connection_lost(exc)

    return GuardedH11Protocol
