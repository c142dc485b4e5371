"""The asyncio driver of the vehicle link: a ``websockets`` client pumping a GraphLinkCore.

Connects to the central server's ``/vehicle-link`` (or any rosbridge v2 endpoint that lets this
token publish), sends the core's hello, then one reader (frames → core) and one writer (core's
queue → socket) until the connection drops; reconnects with exponential backoff (0.2 s doubling
to 2 s). ``last_heard`` is the monotonic time of the last frame from the server, so the vehicle
can tell a stalled central server from a quiet one (the server sends a heartbeat at 10 Hz).

``wss://`` (a central server serving HTTPS, e.g. ``serve --host 0.0.0.0``): the certificate is
verified with ``ca_file`` (else the system's CAs) or pinned by its SHA-256 ``fingerprint``
(``serve`` pins its own for the vehicles it spawns); an untrusted certificate stops the link
with the reason (:class:`~server.vehicles.errors.LinkError`), it is not retried. The reconnect
loop is :class:`~server.vehicles.central_connection.CentralConnection`, shared with the fleet
client.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

from server.http.tls import TLSError
from server.vehicles.central_connection import CentralConnection, CentralServer
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
        try:
            self.conn = CentralConnection(
                CentralServer(url, token, ca_file, fingerprint),
                error=LinkError,
                name=name,
                log=log,
                backoff_s=backoff_s,
                open_timeout_s=5,
            )
        except TLSError as exc:
            raise LinkError(str(exc)) from exc
        self.url = url
        self.core = core
        self.clock = clock
        self.name = name
        self.last_heard: float | None = None
        self._wake = asyncio.Event()
        core.on_output = self._wake.set

    async def run(self, stop: asyncio.Event) -> None:
        """Keep the link up (reconnecting) until ``stop`` is set."""
        await self.conn.run(
            stop, hello=self.core.hello, session=self._session, on_close=self.core.disconnected
        )

    def _session(self, ws: Any) -> list[Coroutine[Any, Any, None]]:
        self.last_heard = self.clock()  # joined: the server counts as heard from now
        return [self._read(ws), self._write(ws)]

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
        await self.conn.drop()
