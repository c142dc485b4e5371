"""The safety door: a vehicle's own small WebSocket for stops, held open by the console page.

A stop must never wait behind the web server (a stalled or stopped ``serve``, a flood of
untrusted frames there). The page therefore opens, at load, a standing connection to each
vehicle's door beside its rosbridge connection, and sends every Land, Hover and Emergency down
both roads at once (docs/safety-door.md). The protocol is :mod:`server.vehicles.door_protocol`;
the WebSocket framing is websockets' sans-I/O :class:`~websockets.server.ServerProtocol`, and
this module only pumps bytes between it and an asyncio stream: no web framework in the vehicle.

What keeps a held connection from being displaced:

- A connection must authenticate (``auth`` with the pilot token or a pilot ticket) within
  ``auth_deadline_s`` of the TCP accept, the TLS and WebSocket handshakes included, or it is
  closed; frames are capped at 4 KB (close 1009 above).
- Connections not yet authenticated are capped per source address and in all; one over either
  cap is closed unread at accept. Authenticated connections are counted apart, with capacity
  of their own: no number of connections without a token takes their places.
- A client that does not read its heartbeats (its socket buffer over ``write_buffer_max``) is
  closed, so no connection holds the vehicle's memory.

It listens where ``serve`` does: loopback by default, a LAN address with ``serve --host``; then
over TLS with ``serve``'s certificate when ``serve`` speaks HTTPS (a ``wss:`` URL for an HTTPS
page). :func:`advertised_url` gives the URL a page calls; :func:`page_origin` and
:func:`loopback_origin` say which browser pages may open it (the token is still required).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import logging
import ssl
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from urllib.parse import urlsplit

from websockets.exceptions import InvalidState
from websockets.frames import Frame, Opcode
from websockets.http11 import Request
from websockets.server import ServerProtocol

from server.http.security import parse_host
from server.vehicles.door_protocol import (
    AUTH_DEADLINE_S,
    MAX_FRAME_BYTES,
    Ack,
    Auth,
    ClientMessage,
    DoorMessage,
    DoorPhase,
    DoorSession,
    Error,
    Heartbeat,
    Hello,
    Stop,
    Supersede,
    Superseded,
    encode,
)
from server.vehicles.errors import DoorError, DoorProtocolError
from server.vehicles.tickets import looks_like_ticket, verify

log = logging.getLogger(__name__)

WILDCARDS = ("", "0.0.0.0", "::")
CLOSE_POLICY = 1008  # RFC 6455 §7.4.1: policy violation (a bad token, a bad first frame)
# RFC 6455 §7.4.1 (IANA registry): try again later: the door is full, or the auth came too
# late (on a busy machine the door itself may be slow to read it: a page retries at once,
# where after 1008, a refused credential, it waits)
CLOSE_TRY_LATER = 1013
# Past the auth deadline, a read still waits this long for what the client has sent: time the
# door itself spent not running (a busy machine) does not count against a client on time; no
# client stays unauthenticated past AUTH_HARD_FACTOR times the deadline from its accept.
AUTH_READ_GRACE_S = 0.25
AUTH_HARD_FACTOR = 3.0
MAX_BAD_FRAMES = 16  # an authenticated client's refused frames before it is closed
CLOSE_LINGER_S = 1.0  # after a close frame, how long the peer has to answer before abort


@dataclass(frozen=True)
class DoorLimits:
    """How many connections the door holds, and how long it waits for a token."""

    unauthenticated_per_address: int = 4
    unauthenticated: int = 32
    authenticated: int = 32  # reserved: never taken by the unauthenticated
    auth_deadline_s: float = AUTH_DEADLINE_S
    write_buffer_max: int = 64 * 1024


@dataclass
class DoorCounts:
    """What the door holds and has done (for tests, logs and benchmarks)."""

    unauthenticated: Counter[str] = field(default_factory=Counter)
    authenticated: int = 0
    refused_at_accept: int = 0
    auth_failed: int = 0
    auth_timeouts: int = 0
    stops: int = 0

    @property
    def unauthenticated_total(self) -> int:
        return sum(self.unauthenticated.values())


# role for a token (raises DoorError with the reason when it is refused)
Authenticate = Callable[[str], str]
StopHandler = Callable[[Stop], Ack]
SupersedeHandler = Callable[[Supersede], Superseded]
StatusSource = Callable[[], tuple[str, bool]]  # (flight state, drone link ok)


class SafetyDoor:
    """Serve the door on ``host:port`` (0: any free port, see :attr:`port`).

    Args:
        drone: the vehicle's name (said in ``hello``).
        authenticate: the role a token grants; raises :class:`DoorError` saying why not.
            Only ``pilot`` may open the door.
        on_stop: runs a stop (once per id, whichever road) and answers it.
        on_supersede: drops stop ids that have not run.
        status: the drone's flight state and link, for the heartbeats.
        origin_allowed: whether a browser page of this ``Origin`` may connect, given the
            request's ``Host`` (None: any loopback page, see :func:`loopback_origin`).
        tls: serve ``wss:`` with this context (None: ``ws:``).
        clock: unix time (``hello``, heartbeats); monotonic: deadlines.
    """

    def __init__(
        self,
        host: str,
        port: int,
        *,
        drone: str,
        authenticate: Authenticate,
        on_stop: StopHandler,
        on_supersede: SupersedeHandler,
        status: StatusSource,
        origin_allowed: Callable[[str, str | None], bool] | None = None,
        tls: ssl.SSLContext | None = None,
        limits: DoorLimits | None = None,
        clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.host = host
        self.port = port
        self.drone = drone
        self.authenticate = authenticate
        self.on_stop = on_stop
        self.on_supersede = on_supersede
        self.status = status
        self.origin_allowed = origin_allowed or (lambda origin, _host: loopback_origin(origin))
        self.tls = tls
        self.limits = limits or DoorLimits()
        self.clock = clock
        self.monotonic = monotonic
        self.counts = DoorCounts()
        self._server: asyncio.Server | None = None
        self._conns: set[asyncio.Task[None]] = set()

    @property
    def url(self) -> str:
        """Where it listens (a wildcard host as bound: see :func:`advertised_url`)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'wss' if self.tls else 'ws'}://{host}:{self.port}"

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._accept, self.host or None, self.port, limit=MAX_FRAME_BYTES * 2
        )
        self.port = int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._conns):
            task.cancel()
        for task in list(self._conns):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self._server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 2.0)
            self._server = None

    # ------------------------------------------------------------------ admission
    def _admit(self, address: str) -> bool:
        c, lim = self.counts, self.limits
        if (
            c.unauthenticated[address] >= lim.unauthenticated_per_address
            or c.unauthenticated_total >= lim.unauthenticated
        ):
            c.refused_at_accept += 1
            return False
        c.unauthenticated[address] += 1
        return True

    def _leave_unauthenticated(self, address: str) -> None:
        c = self.counts
        c.unauthenticated[address] -= 1
        if c.unauthenticated[address] <= 0:
            del c.unauthenticated[address]

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        address = str(peer[0]) if isinstance(peer, tuple) and peer else "?"
        if not self._admit(address):
            writer.transport.abort()  # a flood: closed unread, nothing answered
            return
        task = asyncio.current_task()
        assert task is not None
        self._conns.add(task)
        conn = _Connection(self, reader, writer, address)
        try:
            await conn.run()
        except asyncio.CancelledError:
            # stop() ends every connection; end the task as done, not cancelled (asyncio's
            # server callback would log a cancelled client task as an error)
            pass
        finally:
            self._conns.discard(task)
            if conn.counted_authenticated:
                self.counts.authenticated -= 1
            else:
                self._leave_unauthenticated(address)
            conn.abort()

    def _take_authenticated_slot(self, address: str) -> bool:
        if self.counts.authenticated >= self.limits.authenticated:
            return False
        self._leave_unauthenticated(address)
        self.counts.authenticated += 1
        return True


class _Connection:
    """One client: TLS, the WebSocket handshake, ``auth``, then stops and heartbeats."""

    def __init__(
        self,
        door: SafetyDoor,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        address: str,
    ) -> None:
        self.door = door
        self.reader = reader
        self.writer = writer
        self.address = address
        self.ws = ServerProtocol(max_size=MAX_FRAME_BYTES)
        self.session = DoorSession(door.monotonic(), door.limits.auth_deadline_s)
        self.counted_authenticated = False
        self.bad_frames = 0
        self._parts: list[bytes] = []  # a fragmented text message being assembled
        self._beats: asyncio.Task[None] | None = None

    def _left(self) -> float:
        return self.session.auth_deadline - self.door.monotonic()

    def _hard_left(self) -> float:
        extra = (AUTH_HARD_FACTOR - 1.0) * self.door.limits.auth_deadline_s
        return self._left() + extra

    def _late_auth(self) -> str:
        return f"no auth within {self.door.limits.auth_deadline_s:g} s of connecting"

    async def run(self) -> None:
        try:
            if self.door.tls is not None:
                # Awaited directly, not under wait_for: a task of its own would start a loop
                # turn later, when the ClientHello may already sit in the plain stream.
                await self.writer.start_tls(
                    self.door.tls, ssl_handshake_timeout=max(self._left(), 0.01)
                )
            while self.session.phase is not DoorPhase.CLOSED:
                if self.session.phase is DoorPhase.AWAITING_AUTH:
                    # The deadline is judged by a read that waited for the client in vain, not
                    # by the clock alone: what came while the door was not running is read.
                    if self._hard_left() <= 0:
                        self.door.counts.auth_timeouts += 1
                        self._close(CLOSE_TRY_LATER, self._late_auth())
                        break
                    wait = min(max(self._left(), AUTH_READ_GRACE_S), self._hard_left())
                    data = await asyncio.wait_for(self.reader.read(MAX_FRAME_BYTES), wait)
                else:
                    data = await self.reader.read(MAX_FRAME_BYTES)
                if not data:
                    self.ws.receive_eof()
                    break
                self.ws.receive_data(data)
                self._handle_events()
                self._flush()
                if self.ws.close_expected():
                    break
        except TimeoutError:
            if self.session.phase is DoorPhase.AWAITING_AUTH:
                self.door.counts.auth_timeouts += 1
                with contextlib.suppress(Exception):
                    self._close(CLOSE_TRY_LATER, self._late_auth())
        except (OSError, ssl.SSLError, ConnectionError):
            pass
        finally:
            if self._beats is not None:
                self._beats.cancel()
        await self._linger()

    # ------------------------------------------------------------------ events
    def _handle_events(self) -> None:
        """Everything one read brought. Once open, a batch's ``supersede`` messages are
        handled before its stops: frames read together arrived while the vehicle was busy or
        stopped, and a stop superseded behind it must not fire from the past."""
        batch: list[ClientMessage] = []
        for event in self.ws.events_received():
            if isinstance(event, Request):
                self._handshake(event)
            elif isinstance(event, Frame):
                msg = self._frame(event)
                if msg is None:
                    continue
                if self.session.phase is DoorPhase.OPEN and not isinstance(msg, Auth):
                    batch.append(msg)
                else:
                    self._message(msg)  # auth: what follows is judged by its outcome
        batch.sort(key=lambda m: not isinstance(m, Supersede))  # stable: order kept otherwise
        for msg in batch:
            self._message(msg)

    def _handshake(self, request: Request) -> None:
        origin = request.headers.get("Origin")
        host = request.headers.get("Host")
        if origin is not None and not self.door.origin_allowed(origin, host):
            response = self.ws.reject(403, "Origin not allowed\n")
        else:
            response = self.ws.accept(request)
        self.ws.send_response(response)

    def _frame(self, frame: Frame) -> ClientMessage | None:
        """The message a frame completes (None: a control frame, a fragment, a refusal)."""
        if self.session.phase is DoorPhase.CLOSED:
            return None
        if frame.opcode is Opcode.TEXT:
            self._parts = [bytes(frame.data)]
        elif frame.opcode is Opcode.CONT and self._parts:
            self._parts.append(bytes(frame.data))
        elif frame.opcode is Opcode.BINARY:
            self._refuse_frame("the door takes JSON text frames")
            return None
        else:
            return None  # ping, pong and close are websockets' business
        if sum(len(p) for p in self._parts) > MAX_FRAME_BYTES:
            self._parts = []
            self._close(1009, f"message over {MAX_FRAME_BYTES} bytes")
            return None
        if not frame.fin:
            return None
        text, self._parts = b"".join(self._parts), []
        try:
            return self.session.receive(text)
        except DoorProtocolError as exc:
            if self.session.closed:  # before auth: anything wrong ends the connection
                self.door.counts.auth_failed += 1
                self._close(CLOSE_POLICY, str(exc))
            else:
                self._refuse_frame(str(exc))
            return None

    def _refuse_frame(self, why: str) -> None:
        self.bad_frames += 1
        self._send(Error(why))
        if self.bad_frames > MAX_BAD_FRAMES:
            self._close(CLOSE_POLICY, "too many refused frames")

    def _message(self, msg: ClientMessage) -> None:
        door = self.door
        if self.session.phase is DoorPhase.CLOSED:
            return
        if isinstance(msg, Auth):
            try:
                role = door.authenticate(msg.token)
                if role != "pilot":
                    raise DoorError(f"an {role} may not stop the drone: a pilot's token is needed")
            except DoorError as exc:
                door.counts.auth_failed += 1
                self.session.refuse()
                self._close(CLOSE_POLICY, str(exc))
                return
            if not door._take_authenticated_slot(self.address):
                self.session.refuse()
                self._close(CLOSE_TRY_LATER, "the door is full: try again later")
                return
            self.counted_authenticated = True
            self.session.authenticated(role, door.monotonic())
            self._send(Hello(door.drone, door.clock()))
            self._beats = asyncio.get_running_loop().create_task(self._heartbeats())
        elif isinstance(msg, Stop):
            door.counts.stops += 1
            self._send(door.on_stop(msg))
        elif isinstance(msg, Supersede):
            self._send(door.on_supersede(msg))

    async def _heartbeats(self) -> None:
        door = self.door
        while self.session.phase is DoorPhase.OPEN:
            now = door.monotonic()
            if self.session.heartbeat_due(now):
                state, link_ok = door.status()
                self._send(Heartbeat(door.clock(), state, link_ok))
                self._flush()
            wait = (self.session.next_heartbeat or now) - door.monotonic()
            await asyncio.sleep(max(wait, 0.005))

    # ------------------------------------------------------------------ output
    def _send(self, msg: DoorMessage) -> None:
        with contextlib.suppress(InvalidState):
            self.ws.send_text(encode(msg).encode())

    def _close(self, code: int, reason: str) -> None:
        self.session.refuse()
        with contextlib.suppress(InvalidState):
            self.ws.send_close(code, reason[:120])
        self._flush()

    def _flush(self) -> None:
        transport = self.writer.transport
        if transport.is_closing():
            return
        for chunk in self.ws.data_to_send():
            if chunk:
                transport.write(chunk)
            elif transport.can_write_eof():
                transport.write_eof()
        if transport.get_write_buffer_size() > self.door.limits.write_buffer_max:
            log.warning("%s: door client %s does not read: closed", self.door.drone, self.address)
            self.session.refuse()
            transport.abort()

    async def _linger(self) -> None:
        """Give a close frame a moment to reach the peer, then let go of the socket."""
        self._flush()
        transport = self.writer.transport
        if transport.is_closing():
            return
        transport.close()
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.writer.wait_closed(), CLOSE_LINGER_S)

    def abort(self) -> None:
        with contextlib.suppress(Exception):
            self.writer.transport.abort()


def door_authenticator(
    pilot_token: str,
    secret: bytes | None,
    drone: str,
    clock: Callable[[], float] = time.time,
) -> Authenticate:
    """The door's ``authenticate``: the pilot token, or a ticket for this drone signed with
    the vehicle's door secret (checked here alone: it works while the console is down). The
    observer token is not known to a vehicle; an observer's ticket names its role and is
    refused by the door."""

    def authenticate(token: str) -> str:
        if looks_like_ticket(token):
            if secret is None:
                raise DoorError("this vehicle takes no tickets: use the pilot token")
            return verify(secret, token, drone, clock())
        raw = token.encode("utf-8", "surrogatepass")
        if hmac.compare_digest(raw, pilot_token.encode()):
            return "pilot"
        raise DoorError("the pilot token or a pilot's door ticket is required")

    return authenticate


# ---------------------------------------------------------------------- addresses and origins
def loopback_origin(origin: str) -> bool:
    host = urlsplit(origin).hostname or ""
    return host in ("localhost", "::1") or host.startswith("127.")


def page_origin(origin: str, host_header: str | None, console_port: int) -> bool:
    """Whether ``origin`` is the console's page on the host this request names: the same
    host name (an IP literal, ``localhost`` or a single-label name, which an attacker's DNS
    cannot re-point: the DNS-rebinding rule of ``Security.host_allowed``) on the console's
    port. The token is still required; this only keeps other sites' pages out."""
    if not host_header:
        return False
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return False
    try:
        port = parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError:
        return False
    parsed = parse_host(host_header, 0)
    if parsed is None or parsed[0] != parts.hostname.lower() or port != console_port:
        return False
    name = parsed[0].strip("[]")
    return _is_ip(name) or name == "localhost" or "." not in name


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def advertised_url(bound: str | None, host_header: str | None) -> str | None:
    """The door's URL for a page (or script) that reached the console with this ``Host``: a
    door bound to one loopback address keeps it (the page is on this machine); one bound to a
    wildcard or a LAN address gets the host the request named, so a phone calls the address it
    already reaches. The scheme and port stay the door's own. None when there is no door, or
    no usable host for a wildcard."""
    if not bound:
        return None
    parts = urlsplit(bound)
    try:
        port = parts.port
    except ValueError:
        return None
    hostname = parts.hostname or ""
    if hostname not in WILDCARDS and _loopback(hostname):
        return bound
    parsed = parse_host(host_header, 0) if host_header else None
    if parsed is None:
        return None if hostname in WILDCARDS else bound
    name = parsed[0].strip("[]")
    host = f"[{name}]" if ":" in name else name
    return f"{parts.scheme}://{host}:{port}"


def _loopback(hostname: str) -> bool:
    if hostname == "localhost":
        return True
    try:
        return ipaddress.ip_address(hostname).is_loopback
    except ValueError:
        return False
