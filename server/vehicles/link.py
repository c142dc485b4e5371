"""The asyncio driver of the vehicle link: a ``websockets`` client pumping a GraphLinkCore.

Connects to the central server's ``/vehicle-link`` (or any rosbridge v2 endpoint that lets this
token publish), sends the core's hello, then one reader (frames → core) and one writer (core's
queue → socket) until the connection drops; reconnects with exponential backoff (0.2 s doubling
to 2 s). ``last_heard`` is the monotonic time of the last frame from the server, so the vehicle
can tell a stalled central server from a quiet one (the server sends a heartbeat at 10 Hz).

``wss://`` (a central server serving HTTPS, e.g. ``serve --host 0.0.0.0``): the certificate is
verified with ``ca_file`` (else the system's CAs) or pinned by its SHA-256 ``fingerprint``
(``serve`` pins its own for the vehicles it spawns); an untrusted certificate stops the link
with the reason (:class:`~server.vehicles.errors.LinkError`), it is not retried.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from server.tls import TLSError, check_pinned, client_context, untrusted
from server.vehicles.errors import LinkError
from server.vehicles.link_core import GraphLinkCore

log = logging.getLogger(__name__)


class GraphLink:
    """See the module docstring. ``run(stop)`` returns when ``stop`` is set."""

    def __init__(
        self,
        url: str,
        core: GraphLinkCore,
        *,
        token: str | None = None,
        clock: Callable[[], float] = time.monotonic,
        backoff_s: tuple[float, float] = (0.2, 2.0),
        name: str = "vehicle",
        ca_file: Path | None = None,
        fingerprint: str | None = None,
    ) -> None:
        if not url.startswith(("ws://", "wss://")):
            raise LinkError(f"--central must be a ws:// or wss:// URL, got {url!r}")
        self.url = url
        self.fingerprint = fingerprint
        try:
            self.ssl: ssl.SSLContext | None = (
                client_context(ca_file, fingerprint) if url.startswith("wss://") else None
            )
        except TLSError as exc:
            raise LinkError(str(exc)) from exc
        self.core = core
        self.token = token
        self.clock = clock
        self.backoff_s = backoff_s
        self.name = name
        self.connects = 0
        self.connected = asyncio.Event()
        self.last_heard: float | None = None
        self._wake = asyncio.Event()
        core.on_output = self._wake.set
        self._ws: Any | None = None

    async def run(self, stop: asyncio.Event) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import InvalidHandshake, WebSocketException

        delay = self.backoff_s[0]
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        while not stop.is_set():
            try:
                async with connect(
                    self.url,
                    additional_headers=headers,
                    max_size=None,
                    open_timeout=5,
                    ssl=self.ssl,
                ) as ws:
                    if self.ssl is not None and self.fingerprint is not None:
                        check_pinned(ws.transport.get_extra_info("ssl_object"), self.fingerprint)
                    self._ws = ws
                    for frame in self.core.hello():
                        await ws.send(frame)
                    self.connects += 1
                    self.last_heard = self.clock()
                    self.connected.set()
                    delay = self.backoff_s[0]
                    log.info("%s joined %s", self.name, self.url)
                    parts = [self._read(ws), self._write(ws), stop.wait()]
                    tasks = [asyncio.create_task(p) for p in parts]
                    await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
                    for t in tasks:
                        t.cancel()
                        with contextlib.suppress(asyncio.CancelledError, Exception):
                            await t
            except ssl.SSLCertVerificationError as exc:
                raise LinkError(untrusted(exc)) from exc
            except TLSError as exc:
                raise LinkError(str(exc)) from exc
            except (OSError, InvalidHandshake, WebSocketException, TimeoutError) as exc:
                log.warning("%s: central server unreachable (%s); retrying", self.name, exc)
            finally:
                self._ws = None
                self.connected.clear()
                self.core.disconnected()
            if stop.is_set():
                break
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), delay)
            delay = min(delay * 2, self.backoff_s[1])

    async def _read(self, ws: Any) -> None:
        async for text in ws:
            self.last_heard = self.clock()
            if isinstance(text, str):
                self.core.receive(text)

    async def _write(self, ws: Any) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            for frame in self.core.drain():
                await ws.send(frame)

    async def drop(self) -> None:
        """Close the current connection (it reconnects after the backoff); for drills."""
        if self._ws is not None:
            await self._ws.close()
