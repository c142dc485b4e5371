"""A TCP relay on loopback that a test cuts and heals: a network outage between a client and
its server (a vehicle and its bus router), with both ends running on as they would."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Iterator

from tests.support.polling import until

CHUNK = 65536


class Relay:
    """Accepts on ``127.0.0.1`` (a port the OS picks) and relays each connection to
    ``host:port``. :meth:`cut` aborts every relayed connection and refuses new ones until
    :meth:`heal`. Runs its own event loop in a daemon thread (:func:`relay` starts and stops it).
    """

    def __init__(self, host: str, port: int) -> None:
        self.host = host
        self.port = port
        self.listen_port = 0
        self.accepted = 0  # connections relayed since the start
        self.refused = 0  # connections refused while cut
        self._down = False
        self._open: set[asyncio.StreamWriter] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.Server | None = None
        self._thread = threading.Thread(target=self._run, name="relay", daemon=True)
        self._ready = threading.Event()
        self._stopped: asyncio.Event | None = None

    @property
    def endpoint(self) -> str:
        """The relay as a Zenoh endpoint."""
        return f"tcp/127.0.0.1:{self.listen_port}"

    def start(self) -> None:
        self._thread.start()
        until(self._ready.is_set, 10.0, "the relay to listen")

    def _run(self) -> None:
        asyncio.run(self._main())

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stopped = asyncio.Event()
        self._server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        self.listen_port = int(self._server.sockets[0].getsockname()[1])
        self._ready.set()
        await self._stopped.wait()
        self._server.close()
        self._abort_all()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._down:
            self.refused += 1
            writer.transport.abort()
            return
        try:
            up_reader, up_writer = await asyncio.open_connection(self.host, self.port)
        except OSError:
            writer.transport.abort()
            return
        self.accepted += 1
        self._open |= {writer, up_writer}
        try:
            await asyncio.gather(self._pipe(reader, up_writer), self._pipe(up_reader, writer))
        finally:
            self._open -= {writer, up_writer}

    async def _pipe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while data := await reader.read(CHUNK):
                writer.write(data)
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.transport.abort()

    def _abort_all(self) -> None:
        for w in list(self._open):
            w.transport.abort()
        self._open.clear()

    async def _switch(self, down: bool) -> None:
        self._down = down
        if down:
            self._abort_all()

    def cut(self) -> None:
        """The link goes down: every relayed connection is aborted, new ones are refused."""
        assert self._loop is not None
        asyncio.run_coroutine_threadsafe(self._switch(True), self._loop).result(10)

    def heal(self) -> None:
        """The link is back: new connections are relayed again."""
        assert self._loop is not None
        asyncio.run_coroutine_threadsafe(self._switch(False), self._loop).result(10)

    def stop(self) -> None:
        if self._loop is not None and self._stopped is not None:
            self._loop.call_soon_threadsafe(self._stopped.set)
        self._thread.join(10)


@contextlib.contextmanager
def relay(host: str, port: int) -> Iterator[Relay]:
    """A :class:`Relay` to ``host:port`` for the block."""
    r = Relay(host, port)
    r.start()
    try:
        yield r
    finally:
        r.stop()
