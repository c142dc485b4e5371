"""A client's connection to the central server, kept open: the one reconnect loop behind the
``vehicle`` command's fleet client (:mod:`server.fleet.client`) and the vehicle process's graph
link (:mod:`server.vehicles.link`).

:meth:`CentralConnection.run` connects to a ``ws://`` or ``wss://`` URL (``Authorization:
Bearer`` token; a ``wss://`` certificate verified with a CA file, else the system's CAs, or
pinned by its SHA-256 fingerprint, see :mod:`server.http.tls`), sends the caller's hello
frames, then
races the caller's session coroutines (its reader, a writer) against ``stop`` until one ends,
cancels the rest and reconnects after an exponential backoff (``backoff_s[0]`` doubling to
``backoff_s[1]``; longer after :meth:`CentralConnection.drop` with a hold). An unreachable server
is logged and retried; an untrusted or wrongly pinned certificate is not: it raises the caller's
error class with the reason. What differs between the callers (URL, error class, what to do once
connected, names and logger for the log lines) is passed in.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
from collections.abc import Callable, Coroutine, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from server.http.tls import TLSError, check_pinned, client_context, untrusted


@dataclass(frozen=True)
class CentralServer:
    """Where the central server is and how to trust it."""

    url: str  # ``ws://`` or ``wss://`` URL of its endpoint
    token: str | None = None  # sent as ``Authorization: Bearer``
    ca_file: Path | None = None  # ``wss://``: verify with this CA (else the system's CAs) …
    fingerprint: str | None = None  # … or accept exactly the certificate with this SHA-256


class CentralConnection:
    """See the module docstring.

    Args:
        server: the URL, token and how to trust its certificate.
        error: the caller's error class, raised with the reason for a URL that is not
            ``ws(s)://`` and for a certificate that is not trusted (or not the pinned one).
        name: who is connecting, in the log lines (``uav1 joined …``).
        log: the caller's logger, so the lines keep the caller's logger name.
        backoff_s: first and longest wait between attempts.
        open_timeout_s: how long one attempt (TCP, TLS, WebSocket handshake) may take.

    Raises:
        error: ``url`` is not a ``ws://`` or ``wss://`` URL.
        TLSError: the CA file cannot be read.
    """

    def __init__(
        self,
        server: CentralServer,
        *,
        error: type[Exception],
        name: str,
        log: logging.Logger,
        backoff_s: tuple[float, float],
        open_timeout_s: float = 10.0,
    ) -> None:
        url = server.url
        if not url.startswith(("ws://", "wss://")):
            raise error(f"--central must be a ws:// or wss:// URL, got {url!r}")
        self.url = url
        self.error = error
        self.name = name
        self.log = log
        self.backoff_s = backoff_s
        self.headers = {"Authorization": f"Bearer {server.token}"} if server.token else {}
        self.fingerprint = server.fingerprint
        self.ssl: ssl.SSLContext | None = (
            client_context(server.ca_file, server.fingerprint) if url.startswith("wss://") else None
        )
        self.open_timeout_s = open_timeout_s
        self.ws: Any | None = None  # the open connection, None between connections
        self.connects = 0
        self.connected = asyncio.Event()
        self._hold_until = 0.0  # loop time before which no reconnect is tried (``drop``)

    async def run(
        self,
        stop: asyncio.Event,
        *,
        hello: Callable[[], Iterable[str]],
        session: Callable[[Any], list[Coroutine[Any, Any, None]]],
        on_close: Callable[[], None] | None = None,
    ) -> None:
        """Keep a connection open until ``stop`` is set.

        Args:
            hello: the frames to send right after each (re)connection.
            session: given the open connection, the coroutines to run while it lasts (they race
                ``stop``; the first to end closes the session and cancels the others).
            on_close: called after each connection (or attempt) ends.

        Raises:
            error: the server's certificate is not trusted or not the pinned one.
        """
        from websockets.asyncio.client import connect
        from websockets.exceptions import InvalidHandshake, WebSocketException

        from server.http.ws_deflate import PlainLargeClientFactory

        delay = self.backoff_s[0]
        while not stop.is_set():
            try:
                async with connect(
                    self.url,
                    additional_headers=self.headers,
                    max_size=None,
                    # camera frames go uncompressed; telemetry stays deflated
                    # (server.http.ws_deflate)
                    compression=None,
                    extensions=[PlainLargeClientFactory()],
                    open_timeout=self.open_timeout_s,
                    ssl=self.ssl,
                ) as ws:
                    if self.ssl is not None and self.fingerprint is not None:
                        check_pinned(ws.transport.get_extra_info("ssl_object"), self.fingerprint)
                    self.ws = ws
                    for frame in hello():
                        await ws.send(frame)
                    self.connects += 1
                    self.connected.set()
                    delay = self.backoff_s[0]
                    self.log.info("%s joined %s", self.name, self.url)
                    tasks = [asyncio.create_task(c) for c in [*session(ws), stop.wait()]]
                    await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
                    for t in tasks:
                        t.cancel()
                        with contextlib.suppress(asyncio.CancelledError, Exception):
                            await t
            except ssl.SSLCertVerificationError as exc:
                raise self.error(untrusted(exc)) from exc
            except TLSError as exc:
                raise self.error(str(exc)) from exc
            except (OSError, InvalidHandshake, WebSocketException, TimeoutError) as exc:
                self.log.warning("%s: central server unreachable (%s); retrying", self.name, exc)
            finally:
                self.ws = None
                self.connected.clear()
                if on_close is not None:
                    on_close()
            if stop.is_set():
                break
            loop = asyncio.get_running_loop()
            wait = max(delay, self._hold_until - loop.time())
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), wait)
            delay = min(delay * 2, self.backoff_s[1])

    async def drop(self, hold_s: float = 0.0) -> None:
        """Close the current connection and stay away at least ``hold_s`` before reconnecting
        (a network outage, for tests and drills)."""
        self._hold_until = asyncio.get_running_loop().time() + hold_s
        if self.ws is not None:
            await self.ws.close()
