"""A frame-size cap before authentication, enforced by the WebSocket transport.

Before it authenticates a connection may send only a small ``auth`` frame. Checking that in the
app is too late: uvicorn has by then read the whole frame (up to ``ws_max_size``, 64 MB) into
memory and decoded it, so back-to-back 16 MB frames without a token still cost the server their
memory and the event loop their copying. :func:`preauth_capped_ws` returns uvicorn's
``websockets-sansio`` protocol class with the cap moved into the frame parser: until the app
lifts it, a frame (or fragmented message) whose header announces more than ``max_bytes`` is
refused as soon as the header is read: the server sends close 1009 (RFC 6455 §7.4.1, message
too big) and a FIN, reads no more, and closes the socket a second later.

How the app lifts it: at the handshake the protocol puts ``{"max_bytes": N, "lift": callable}``
into the ASGI scope's ``extensions`` under :data:`EXTENSION`; :func:`lift_frame_cap` calls it
once the connection has authenticated (a token at the handshake: before ``accept``; the
rosbridge ``auth`` op: after handling it). Under another server (Starlette's ``TestClient``,
uvicorn's other implementations) the extension is absent and the app's own size check stays the
only one.

Frames pipelined behind the ``auth`` frame (one TCP segment holding ``auth`` and a 100 KB
``publish``) must be judged by the outcome of that ``auth``, which the app has not yet decided
when the parser reaches them. So while the cap is on, the parser stops after each complete
message (:class:`_GatedReader`) and reading pauses, until the app asks for the next message,
i.e. has handled this one; then parsing resumes under whatever limit now holds. That costs
nothing: before authentication the app's reader takes one message at a time anyway, and once
the cap is lifted the parser never stops.

Pass it as ``uvicorn.Config(ws=preauth_capped_ws())``. It subclasses uvicorn's and websockets'
internals (``WebSocketsSansIOProtocol.conn``/``queue``/``read_paused``, websockets'
``Protocol.reader``/``max_message_size``), tested against the versions ``pyproject.toml`` pins.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Generator, Mapping
from typing import Any

from uvicorn.config import Config
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from uvicorn.server import ServerState
from websockets.exceptions import PayloadTooBig
from websockets.frames import Frame, Opcode
from websockets.http11 import Request
from websockets.server import ServerProtocol
from websockets.streams import StreamReader

from server.ws_deflate import plain_large

EXTENSION = "uav-console.preauth_frame_cap"
PREAUTH_MAX_BYTES = 4096  # an ``auth`` frame is ~100 bytes
CLOSE_TOO_BIG = 1009  # RFC 6455 §7.4.1: message too big
LINGER_S = 1.0  # after refusing a frame: how long the close frame has before the socket closes

_DATA = (Opcode.TEXT, Opcode.BINARY, Opcode.CONT)


class _GatedReader(StreamReader):
    """websockets' stream reader whose ``at_eof`` (asked before each frame is parsed) waits
    while its protocol holds the parser, so no frame header is judged under a stale limit."""

    def __init__(self, held: Callable[[], bool]) -> None:
        super().__init__()
        self._held = held

    def at_eof(self) -> Generator[None, None, bool]:
        while self._held():
            yield
        return (yield from super().at_eof())


class CappedServerProtocol(ServerProtocol):
    """websockets' sans-I/O server protocol with a lower message limit until :meth:`lift`.

    Attributes:
        capped: the pre-auth limit applies (``max_bytes``); after :meth:`lift`, ``max_size``.
        held: a complete message arrived while capped and the app has not handled it yet;
            the parser parses nothing more until :meth:`release`.
    """

    def __init__(self, max_bytes: int, *, max_size: int | None, **kwargs: Any) -> None:
        self.capped = True
        self.held = False
        self.preauth_max_bytes = max_bytes
        self.full_max_size = max_size
        super().__init__(max_size=max_size, **kwargs)
        self.max_message_size: int | None = max_bytes

    def parse(self) -> Generator[None]:
        # Protocol.__init__ makes a plain reader, then starts this generator before anything
        # is fed: swap the reader in here, before the handshake parser binds its methods.
        if not isinstance(self.reader, _GatedReader):
            self.reader = _GatedReader(lambda: self.held)
        yield from super().parse()

    def recv_frame(self, frame: Frame) -> None:
        super().recv_frame(frame)
        if self.capped and frame.opcode in _DATA and frame.fin:
            self.held = True

    def fail(self, code: int, reason: str = "") -> None:
        if code == CLOSE_TOO_BIG and self.capped:
            reason = (
                f"message over {self.preauth_max_bytes} bytes before authentication "
                "(authenticate first)"
            )
        super().fail(code, reason)

    def lift(self) -> None:
        """The connection authenticated: the transport's full limit from the next frame on."""
        self.capped = False
        self.max_message_size = self.full_max_size

    def release(self) -> None:
        """The app handled the held message: parse what is buffered under the current limit."""
        self.held = False
        if self.parser_exc is None and not self.reader.eof:
            self.receive_data(b"")  # steps the parser; feeds nothing


def lift_frame_cap(scope: Mapping[str, Any]) -> None:
    """Lift the transport's pre-auth cap of this WebSocket (no-op where there is none)."""
    extensions = scope.get("extensions") or {}
    cap = extensions.get(EXTENSION)
    if cap is not None:
        cap["lift"]()


def preauth_capped_ws(max_bytes: int = PREAUTH_MAX_BYTES) -> type[WebSocketsSansIOProtocol]:
    """uvicorn's websockets-sansio protocol class with the pre-auth cap (module docstring)."""

    class PreauthCappedProtocol(WebSocketsSansIOProtocol):
        conn: CappedServerProtocol

        def __init__(
            self,
            config: Config,
            server_state: ServerState,
            app_state: dict[str, Any],
            _loop: asyncio.AbstractEventLoop | None = None,
        ) -> None:
            super().__init__(config, server_state, app_state, _loop)
            plain = self.conn
            self.conn = CappedServerProtocol(
                max_bytes,
                # camera frames go uncompressed (server.ws_deflate): deflate is for telemetry
                extensions=plain_large(plain.available_extensions or []),
                max_size=config.ws_max_size,
                logger=plain.logger,
            )

        def handle_connect(self, event: Request) -> None:
            super().handle_connect(event)
            scope: Any = getattr(self, "scope", None)  # absent when the handshake was refused
            if scope is not None:
                scope["extensions"][EXTENSION] = {"max_bytes": max_bytes, "lift": self.conn.lift}

        def handle_parser_exception(self) -> None:
            exc = self.conn.parser_exc
            if not (self.conn.capped and isinstance(exc, PayloadTooBig)):
                super().handle_parser_exception()
                return
            if self.close_sent:
                return  # lingering (below): uvicorn calls this again for each chunk
            # Like uvicorn's, but a lingering close: the close frame and a FIN now, reading
            # paused, the socket closed LINGER_S later. Closing it at once with the client's
            # frame still arriving would send a reset, and the client could lose the close
            # frame that says why (RFC 7230 §6.6 describes the same for HTTP).
            close = self.conn.close_sent
            code, reason = (close.code, close.reason) if close else (CLOSE_TOO_BIG, "")
            self.queue.put_nowait({"type": "websocket.disconnect", "code": code, "reason": reason})
            self.transport.write(b"".join(self.conn.data_to_send()))
            self.close_sent = True
            self.read_paused = True
            self.transport.pause_reading()
            if self.transport.can_write_eof():
                self.transport.write_eof()
            self.close_timer = self.loop.call_later(LINGER_S, self.transport.close)

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            # A message awaits the app's verdict: read no more than this chunk meanwhile.
            if self.conn.held and not self.read_paused and not self.disconnected:
                self.read_paused = True
                self.transport.pause_reading()

        async def receive(self) -> Any:
            # The app asks for another message with none waiting: it has handled the held one
            # (and lifted the cap if that one authenticated it).
            if self.conn.held and self.queue.empty():
                self._release()
            return await super().receive()

        async def send(self, message: Any) -> None:
            await super().send(message)
            # The app closed without asking for more: parse on, so the peer's close reply
            # ends the closing handshake now (not after uvicorn's 10 s close timer).
            if self.conn.held and self.close_sent:
                self._release()

        def _release(self) -> None:
            if self.disconnected or self.conn.parser_exc is not None:
                self.conn.held = False  # nothing more to parse (already failed or gone)
                return
            self.conn.release()
            if self.conn.parser_exc is not None:
                self.handle_parser_exception()
                return
            self.handle_events()
            if self.read_paused and self.queue.empty():
                self.read_paused = False
                self.transport.resume_reading()

    return PreauthCappedProtocol
