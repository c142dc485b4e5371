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

After authentication the app may lift the cap to a lower limit than the transport's own (an
observer's frames are small: :func:`lift_frame_cap` ``max_bytes``).

permessage-deflate (RFC 7692), which browsers and Node's ``ws`` negotiate, is decoding on the
event loop too: websockets inflates every compressed frame as it parses it, and one read of the
socket (256 KB) can hold thousands of compressed messages, ~1000× their size inflated (an
observer's 60 KB fragments stalled the loop 1.1 s). So the negotiated extension is metered
(:class:`InflateLimits`): one compressed message inflates to at most ``max_message_bytes``
(16 MiB; more: close 1009, the reason says to send it uncompressed); after ``per_turn_bytes`` of
inflation the parser stops at the next frame and resumes on a later turn of the loop; and a
connection's inflation is a token bucket of ``rate_bytes_per_s`` (over it, reading pauses
until it refills: TCP slows the sender). Frames sent uncompressed cost none of it.

Pass it as ``uvicorn.Config(ws=preauth_capped_ws())``. It subclasses uvicorn's and websockets'
internals (``WebSocketsSansIOProtocol.conn``/``queue``/``read_paused``, websockets'
``Protocol.reader``/``max_message_size``), tested against the versions ``pyproject.toml`` pins.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Generator, Mapping
from dataclasses import dataclass
from typing import Any

from uvicorn.config import Config
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from uvicorn.server import ServerState
from websockets.datastructures import Headers
from websockets.exceptions import PayloadTooBig
from websockets.extensions.base import Extension
from websockets.frames import Frame, Opcode
from websockets.http11 import Request
from websockets.server import ServerProtocol
from websockets.streams import StreamReader

from server.http.ws_deflate import plain_large

EXTENSION = "uav-console.preauth_frame_cap"
PREAUTH_MAX_BYTES = 4096  # an ``auth`` frame is ~100 bytes
CLOSE_TOO_BIG = 1009  # RFC 6455 §7.4.1: message too big
LINGER_S = 1.0  # after refusing a frame: how long the close frame has before the socket closes

_DATA = (Opcode.TEXT, Opcode.BINARY, Opcode.CONT)


@dataclass(frozen=True)
class InflateLimits:
    """What permessage-deflate may cost the event loop, per connection (module docstring).

    Attributes:
        max_message_bytes: inflated size of one compressed message: the rosbridge endpoint's
            frame limit (``Settings.max_frame_bytes``), which it would refuse anyway after the
            transport had inflated up to its own limit, 4× more (zlib inflates ~1 GB/s).
        per_turn_bytes: inflated in one turn of the loop before the parser waits for the next.
        rate_bytes_per_s / burst_bytes: the token bucket of inflated bytes (as the rosbridge
            endpoint's bucket of received bytes).
    """

    max_message_bytes: int = 16 << 20
    per_turn_bytes: int = 1 << 20
    rate_bytes_per_s: float = 16 << 20
    burst_bytes: float = 16 << 20


class _MeteredInflate(Extension):
    """The negotiated permessage-deflate, metered: caps what one compressed message inflates
    to and charges each frame's inflated bytes to its protocol."""

    def __init__(self, inner: Extension, protocol: CappedServerProtocol) -> None:
        self.inner = inner
        self.protocol = protocol
        self.name = inner.name
        self.message_bytes = 0  # inflated so far of the compressed message being received
        self.compressed = False  # that message is compressed

    def decode(self, frame: Frame, *, max_size: int | None = None) -> Frame:
        if frame.opcode in (Opcode.TEXT, Opcode.BINARY):
            self.compressed, self.message_bytes = frame.rsv1, 0
        if not self.compressed or frame.opcode not in _DATA:
            return self.inner.decode(frame, max_size=max_size)
        left = self.protocol.inflate.max_message_bytes - self.message_bytes
        if max_size is None or left < max_size:
            self.protocol.inflate_capped = True
            if left <= 0:  # websockets reads a limit of 0 as none
                raise PayloadTooBig(None, self.protocol.inflate.max_message_bytes)
            max_size = left
        else:
            self.protocol.inflate_capped = False
        out = self.inner.decode(frame, max_size=max_size)
        self.message_bytes += len(out.data)
        self.protocol.charge_inflated(len(out.data))
        return out

    def encode(self, frame: Frame) -> Frame:
        return self.inner.encode(frame)


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

    def __init__(
        self,
        max_bytes: int,
        *,
        max_size: int | None,
        inflate: InflateLimits | None = None,
        clock: Callable[[], float] = time.monotonic,
        **kwargs: Any,
    ) -> None:
        self.capped = True
        self.held = False
        self.preauth_max_bytes = max_bytes
        self.full_max_size = max_size
        self.inflate = inflate if inflate is not None else InflateLimits()
        self.clock = clock
        self.inflated_this_turn = 0
        self.inflate_tokens = self.inflate.burst_bytes
        self.inflate_updated = clock()
        self.inflate_capped = False  # the last compressed frame met max_message_bytes
        super().__init__(max_size=max_size, **kwargs)
        self.max_message_size: int | None = max_bytes

    def parse(self) -> Generator[None]:
        # Protocol.__init__ makes a plain reader, then starts this generator before anything
        # is fed: swap the reader in here, before the handshake parser binds its methods.
        if not isinstance(self.reader, _GatedReader):
            self.reader = _GatedReader(lambda: self.held or self.paced)
        yield from super().parse()

    def process_extensions(self, headers: Headers) -> tuple[str | None, list[Extension]]:
        header, accepted = super().process_extensions(headers)
        return header, [_MeteredInflate(e, self) for e in accepted]

    # -- the inflation budget ------------------------------------------------------------
    def charge_inflated(self, n: int) -> None:
        """``n`` bytes were inflated: count them against this turn and the bucket."""
        self._refill()
        self.inflated_this_turn += n
        self.inflate_tokens -= n

    def _refill(self) -> None:
        now = self.clock()
        rate, burst = self.inflate.rate_bytes_per_s, self.inflate.burst_bytes
        self.inflate_tokens = min(burst, self.inflate_tokens + (now - self.inflate_updated) * rate)
        self.inflate_updated = now

    @property
    def paced(self) -> bool:
        """The parser waits: this turn inflated its share, or the bucket is in debt."""
        return self.inflated_this_turn >= self.inflate.per_turn_bytes or self.inflate_tokens < 0

    def next_turn(self) -> float:
        """Start a new turn of the loop; the seconds until the bucket allows parsing again."""
        self.inflated_this_turn = 0
        self._refill()
        if self.inflate_tokens >= 0:
            return 0.0
        return (
            -self.inflate_tokens / self.inflate.rate_bytes_per_s
            if self.inflate.rate_bytes_per_s > 0
            else math.inf
        )

    def step(self) -> None:
        """Parse what is buffered (under the current limits and gates); feeds nothing."""
        if self.parser_exc is None and not self.reader.eof:
            self.receive_data(b"")

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
        elif code == CLOSE_TOO_BIG and self.inflate_capped:
            reason = (
                f"compressed message inflates to over {self.inflate.max_message_bytes} bytes "
                "(send it uncompressed)"
            )
        elif code == CLOSE_TOO_BIG and self.max_message_size != self.full_max_size:
            reason = f"message over {self.max_message_size} bytes (this connection's limit)"
        super().fail(code, reason)

    def lift(self, max_bytes: int | None = None) -> None:
        """The connection authenticated: from the next frame on, the transport's full limit,
        or ``max_bytes`` where the app gives a lower one (never a higher one)."""
        self.capped = False
        limit = self.full_max_size
        if max_bytes is not None and (limit is None or max_bytes < limit):
            limit = max_bytes
        self.max_message_size = limit

    def release(self) -> None:
        """The app handled the held message: parse what is buffered under the current limit."""
        self.held = False
        self.step()


def lift_frame_cap(scope: Mapping[str, Any], max_bytes: int | None = None) -> None:
    """Lift the transport's pre-auth cap of this WebSocket (no-op where there is none), to
    ``max_bytes`` a message where given (the role's limit), else to the transport's own."""
    extensions = scope.get("extensions") or {}
    cap = extensions.get(EXTENSION)
    if cap is not None:
        cap["lift"](max_bytes)


def preauth_capped_ws(  # noqa: C901
    max_bytes: int = PREAUTH_MAX_BYTES, inflate: InflateLimits | None = None
) -> type[WebSocketsSansIOProtocol]:
    """uvicorn's websockets-sansio protocol class with the pre-auth cap and the metered
    permessage-deflate (module docstring).

    Complexity: the subclass is defined inside (it closes over the limits), and the measure
    counts its overridden methods as this function's branches."""

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
                # camera frames go uncompressed (server.http.ws_deflate): deflate is for telemetry
                extensions=plain_large(plain.available_extensions or []),
                max_size=config.ws_max_size,
                logger=plain.logger,
                inflate=inflate,
                clock=self.loop.time,
            )
            self.pace_timer: asyncio.TimerHandle | None = None

        def handle_connect(self, event: Request) -> None:
            super().handle_connect(event)
            scope: Any = getattr(self, "scope", None)  # absent when the handshake was refused
            if scope is not None:
                scope["extensions"][EXTENSION] = {"max_bytes": max_bytes, "lift": self.conn.lift}

        def handle_parser_exception(self) -> None:
            exc = self.conn.parser_exc
            if not isinstance(exc, PayloadTooBig):
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
            if self.pace_timer is None:
                self.conn.next_turn()  # a new turn of the loop (unless waiting on the bucket)
            super().data_received(data)
            # A message awaits the app's verdict, or this turn's inflation is spent: read no
            # more than this chunk meanwhile.
            if (self.conn.held or self.conn.paced) and not self.disconnected:
                self._pause()
            if self.conn.paced:
                self._pace()

        def _pause(self) -> None:
            if not self.read_paused:
                self.read_paused = True
                self.transport.pause_reading()

        def _pace(self) -> None:
            """The parser stopped for the inflation budget: go on in a later turn."""
            if self.pace_timer is not None or self.disconnected:
                return
            self._pause()
            delay = self.conn.next_turn()
            self.pace_timer = self.loop.call_later(delay, self._unpace)

        def _unpace(self) -> None:
            self.pace_timer = None
            if self.disconnected or self.conn.parser_exc is not None:
                return
            delay = self.conn.next_turn()
            if delay > 0:
                self.pace_timer = self.loop.call_later(delay, self._unpace)
                return
            self.conn.step()
            if self.conn.parser_exc is not None:
                self.handle_parser_exception()
                return
            self.handle_events()
            if self.conn.paced:
                self._pace()
            elif self.read_paused and self.queue.empty() and not self.conn.held:
                self.read_paused = False
                self.transport.resume_reading()

        async def receive(self) -> Any:
            # The app asks for another message with none waiting: it has handled the held one
            # (and lifted the cap if that one authenticated it).
            if self.conn.held and self.queue.empty():
                self._release()
            message = await super().receive()
            if self.conn.paced or self.pace_timer is not None:
                self._pause()  # uvicorn resumed reading; the parser is still waiting its turn
            return message

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
            if self.conn.paced:
                self._pace()
            elif self.read_paused and self.queue.empty():
                self.read_paused = False
                self.transport.resume_reading()

    return PreauthCappedProtocol
