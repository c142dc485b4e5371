"""The rosbridge v2 WebSocket endpoint: a thin asyncio driver around protocol + session.

Per connection: Origin and token checks before accepting (refused: HTTP 403), then a reader
that feeds frames to :class:`BridgeProtocol` (what could be expensive to decode goes to the
context's worker pool, ``server.rosbridge.decoder``) and ops to :class:`BridgeSession`, and a
writer that drains a bounded :class:`OutQueue` (oldest dropped) so a client that never reads
stalls nobody; a writer stuck for ``stall_close_s`` closes the connection (1008). Limits
answered with a status error first, then a close code if abused: frames over
``max_frame_bytes`` (1009 on the second; for an observer over ``observer_max_frame_bytes``),
more frames than the token bucket allows (1008 after ``rate_burst`` refused frames
with no pause of a second between them). On close everything the connection put on the graph
is removed.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.metadata
from collections.abc import Callable, Coroutine
from typing import Any

from fastapi import APIRouter, WebSocket
from pydantic import BaseModel
from starlette.websockets import WebSocketDisconnect, WebSocketState

from server.http.security import LEASE_SERVICE, Role, token_from
from server.http.ws_guard import lift_frame_cap
from server.rosbridge.budget import peek_id
from server.rosbridge.context import BridgeContext
from server.rosbridge.errors import FrameTooLarge
from server.rosbridge.inbound import DecodeRequest
from server.rosbridge.limits import OutQueue, TokenBucket
from server.rosbridge.protocol import PROTOCOL_VERSION, BridgeProtocol
from server.rosbridge.rosapi import register_rosapi
from server.rosbridge.session import BridgeSession

__all__ = [
    "BridgeContext",
    "make_router",
    "serve_rosbridge",
    "serve_rosbridge_port",
    "setup_graph",
]

CLOSE_POLICY = 1008  # RFC 6455 §7.4.1: policy violation (auth, Origin, rate, not reading)
CLOSE_TOO_BIG = 1009  # RFC 6455 §7.4.1: message too big
CLOSE_TRY_LATER = 1013  # IANA WebSocket close codes: try again later (connection caps)


def server_version() -> str:
    try:
        return importlib.metadata.version("uav-console")
    except importlib.metadata.PackageNotFoundError:
        return "0.1.0"


class _Connection:
    def __init__(
        self, ws: WebSocket, ctx: BridgeContext, role: Role | None, who: str | None = None
    ) -> None:
        self.ws = ws
        self.ctx = ctx
        s = ctx.settings
        self.loop = asyncio.get_running_loop()
        self.protocol = BridgeProtocol(
            max_frame_bytes=s.max_frame_bytes,
            budget=ctx.decode_budget,
            offload_text_bytes=ctx.offload_decode_bytes,
            offload_binary_bytes=ctx.offload_binary_bytes,
        )
        client = ws.client
        peer = f"{client.host}:{client.port}" if client else "?"
        self.out = OutQueue(ctx.out_queue_frames, ctx.out_queue_bytes)
        self.wake = asyncio.Event()
        self.tasks: set[asyncio.Task[Any]] = set()
        self.session = BridgeSession(
            ctx,
            self.protocol,
            owner=ctx.new_owner(peer),
            role=role,
            who=who,
            notify=self._pump,
            schedule=lambda delay, fn: self.loop.call_later(delay, fn),
            spawn=self._spawn,
        )
        now = ctx.clock()
        self.bucket = TokenBucket(s.rate_limit_per_s, s.rate_burst, now)
        self.byte_bucket = TokenBucket(ctx.byte_rate_per_s, ctx.byte_burst, now)
        self.limited = 0
        self.limited_since = now
        self.oversized = 0
        self.send_started: float | None = None
        self.close_code: tuple[int, str] | None = None
        self._started = now

    def _spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task = self.loop.create_task(coro)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)

    def _pump(self) -> None:
        for frame in self.protocol.frames_to_send():
            self.out.push(frame)
        request = self.session.close_request or self.protocol.close_request
        if request and self.close_code is None:
            self.close_code = request
        self.wake.set()

    def _close(self, code: int, reason: str) -> None:
        if self.close_code is None:
            self.close_code = (code, reason)
        self.wake.set()

    async def run(self) -> None:
        reader = self.loop.create_task(self._reader())
        writer = self.loop.create_task(self._writer())
        watchdog = self.loop.create_task(self._watchdog())
        try:
            await asyncio.wait({reader, writer, watchdog}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            self.session.close()
            self.out.clear()
            for t in (reader, writer, watchdog, *self.tasks):
                t.cancel()
            for t in (reader, writer, watchdog):
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await t
            await self._close_socket()

    async def _close_socket(self) -> None:
        if self.ws.application_state == WebSocketState.DISCONNECTED:
            return
        code, reason = self.close_code or (1000, "")
        # A client that stopped reading cannot take a close frame either: do not wait on it.
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.ws.close(code=code, reason=reason[:120]), 0.5)

    async def _reader(self) -> None:
        ctx = self.ctx
        capped = self.session.role is None
        while self.close_code is None:
            if capped and self.session.role is not None:
                # authenticated by ``auth``: the role's frame limit from now on
                lift_frame_cap(self.ws.scope, ctx.frame_limit(self.session.role))
                capped = False
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            text, data = message.get("text"), message.get("bytes")
            now = ctx.clock()
            size = len(text) if text is not None else len(data or b"")
            if self.session.role is None and size > ctx.preauth_max_bytes:
                # Nothing but a small auth frame before authenticating: refused
                # unread, and the connection closed. (Under ``serve`` the transport already
                # refused it at its header, 1009: ``server.http.ws_guard``.)
                self.protocol.send_status(
                    "error",
                    f"not authenticated: a frame of {size} bytes before auth (at most "
                    f"{ctx.preauth_max_bytes} bytes until authenticated); closing",
                )
                self._pump()
                self._close(CLOSE_POLICY, "large frame before authentication")
                return
            if size > ctx.settings.max_frame_bytes:
                self.oversized += 1
                self.protocol.send_status(
                    "error",
                    f"frame of {size} bytes exceeds the limit of "
                    f"{ctx.settings.max_frame_bytes} bytes; dropped",
                )
                self._pump()
                if self.oversized >= 2:
                    self._close(CLOSE_TOO_BIG, "frames over the size limit")
                continue
            if not self.bucket.take(now) or not self.byte_bucket.take_n(now, size):
                if now - self.limited_since > 1.0:  # within limits for a second: forgiven
                    self.limited = 0
                self.limited_since = now
                if self.limited == 0:
                    self.protocol.send_status(
                        "error",
                        f"rate limit exceeded ({ctx.settings.rate_limit_per_s:g} frames/s, "
                        f"burst {ctx.settings.rate_burst}; {ctx.byte_rate_per_s:g} bytes/s, "
                        f"burst {ctx.byte_burst:g}); frames are being dropped",
                    )
                    self._pump()
                self.limited += 1
                if self.limited > ctx.settings.rate_burst:
                    self._close(CLOSE_POLICY, "rate limit abused")
                continue
            payload: str | bytes = text if text is not None else (data or b"")
            if self.session.role is Role.OBSERVER and size > ctx.observer_max_frame_bytes:
                # An observer only watches: subscribe, call a read-only service, all small.
                self.oversized += 1
                self.protocol.reject(
                    FrameTooLarge(
                        f"frame of {size} bytes refused unread: an observer may send frames of "
                        f"at most {ctx.observer_max_frame_bytes} bytes",
                        id=peek_id(payload),
                    )
                )
                self._pump()
                if self.oversized >= 2:
                    self._close(CLOSE_TOO_BIG, "frames over the observer's size limit")
                continue
            # Small frames are decoded here; anything expensive (large frames, fragment
            # messages, every png) comes back as a DecodeRequest for the worker pool, so the
            # loop the drones' safety shares never runs it.
            items = self.protocol.feed(payload, now)
            while items:
                item = items.pop(0)
                if isinstance(item, DecodeRequest):
                    decoded = await ctx.decoder.decode(item)
                    now = ctx.clock()
                    items[0:0] = self.protocol.receive_decoded(decoded, now, item)
                else:
                    self.session.handle(item, now)
            self._pump()

    async def _writer(self) -> None:
        ws = self.ws
        while True:
            frame = self.out.pop()
            if frame is None:
                if self.close_code is not None:
                    return
                self.wake.clear()
                await self.wake.wait()
                continue
            self.send_started = self.ctx.clock()
            if isinstance(frame, str):
                await ws.send_text(frame)
            else:
                await ws.send_bytes(frame)
            self.send_started = None

    async def _watchdog(self) -> None:
        """Close a client that stopped reading, or one that never authenticated."""
        period = min(self.ctx.stall_close_s, self.ctx.auth_timeout_s) / 4
        while True:
            await asyncio.sleep(period)
            now = self.ctx.clock()
            started = self.send_started
            if started is not None and now - started > self.ctx.stall_close_s:
                self.close_code = (CLOSE_POLICY, "client is not reading")
                raise ConnectionAbortedError("client is not reading")
            if self.session.role is None and now > self._auth_deadline:
                self._close(CLOSE_POLICY, "not authenticated in time")

    @property
    def _auth_deadline(self) -> float:
        return self._started + self.ctx.auth_timeout_s


async def serve_rosbridge(websocket: WebSocket, ctx: BridgeContext) -> None:
    """Serve one rosbridge v2 connection until either side closes it."""
    loop = asyncio.get_running_loop()
    if ctx.graph.loop is None:
        ctx.graph.bind_loop(loop)  # the app normally binds it at startup
    headers = websocket.headers
    if not ctx.security.origin_allowed(headers.get("origin"), headers.get("host")):
        await websocket.close(code=CLOSE_POLICY, reason="Origin not allowed")
        return
    token = token_from(headers, websocket.query_params, websocket.cookies)
    role: Role | None = None
    if token is not None:
        role = ctx.security.role_for(token)
        if role is None:
            await websocket.close(code=CLOSE_POLICY, reason="invalid token")
            return
    ip_key = "ip:" + (websocket.client.host if websocket.client else "?")
    who = ctx.security.identify(token) if role is not None else None
    token_key = f"token:{role.value}" if role is not None else None
    if token_key is not None and who:  # counted per vehicle, not per role
        token_key += f":{who}"
    over = None
    if ctx.connections[ip_key] >= ctx.max_connections_per_ip:
        over = f"too many connections from this address (at most {ctx.max_connections_per_ip})"
    elif token_key is not None and ctx.connections[token_key] >= ctx.max_connections_per_token:
        over = f"too many connections with this token (at most {ctx.max_connections_per_token})"
    if over is not None:
        # Accepted only to say why (a refused handshake is a bare 403), then closed at once.
        await websocket.accept()
        await websocket.close(code=CLOSE_TRY_LATER, reason=over)
        return
    keys = [k for k in (ip_key, token_key) if k is not None]
    for k in keys:
        ctx.connections[k] += 1
    if role is not None:
        # before the client can send its first frame
        lift_frame_cap(websocket.scope, ctx.frame_limit(role))
    try:
        await websocket.accept()
        conn = _Connection(websocket, ctx, role, who)
        with contextlib.suppress(WebSocketDisconnect, ConnectionAbortedError, OSError):
            await conn.run()
    finally:
        for k in keys:
            ctx.connections[k] -= 1
            if ctx.connections[k] <= 0:
                del ctx.connections[k]


def setup_graph(ctx: BridgeContext) -> None:
    """Put rosapi and the pilot-lease service on the graph (idempotent)."""
    if ctx.graph.service_type("/rosapi/topics") is None:
        register_rosapi(ctx.graph, wall_clock=ctx.wall_clock, request_fields=ctx.request_fields)
    if ctx.graph.service_type(LEASE_SERVICE) is None:
        lease = ctx.security.lease

        async def lease_status(args: dict[str, Any]) -> dict[str, Any]:
            # Bridge clients are answered by their session (it knows who asks); this serves
            # internal callers, which only read the state.
            st = lease.state
            holder = lease.PUBLIC_NAME if st.holder else ""
            return {"holder": holder, "held_by_me": False, "since": st.since or 0.0, "key": ""}

        ctx.graph.advertise_service(LEASE_SERVICE, "uav_console/Lease", lease_status)


class RosbridgeProtocol(BaseModel):
    major: int
    minor: int
    name: str


class VersionInfo(BaseModel):
    """``GET /version``: the rosbridge protocol spoken at ``/rosbridge`` and this server."""

    protocol: RosbridgeProtocol
    server: str


def make_router(ctx: BridgeContext, *, root_ws: bool = False) -> APIRouter:
    """``GET /version`` and the ``/rosbridge`` WebSocket (also ``/`` when ``root_ws``)."""
    setup_graph(ctx)
    router = APIRouter()

    @router.get("/version", response_model=VersionInfo)
    async def version() -> VersionInfo:
        major, minor = PROTOCOL_VERSION
        return VersionInfo(
            protocol=RosbridgeProtocol(major=major, minor=minor, name="rosbridge"),
            server=f"uav-console {server_version()}",
        )

    async def ws_route(websocket: WebSocket) -> None:
        await serve_rosbridge(websocket, ctx)

    router.add_api_websocket_route("/rosbridge", ws_route)
    if root_ws:
        router.add_api_websocket_route("/", ws_route)
    return router


async def serve_rosbridge_port(
    host: str,
    port: int,
    ctx: BridgeContext,
    *,
    started: Callable[[], None] | None = None,
) -> None:
    """Serve rosbridge on its own port (e.g. 9090) at ``/`` and ``/rosbridge`` until cancelled."""
    import uvicorn
    from fastapi import FastAPI

    from server.http.conn_guard import KEEP_ALIVE_S, ConnectionLimits, guarded_h11
    from server.http.http_guard import HttpGuard
    from server.http.ws_guard import preauth_capped_ws

    app = FastAPI(title="uav-console rosbridge")
    app.add_middleware(HttpGuard, security=ctx.security)
    app.include_router(make_router(ctx, root_ws=True))
    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level="warning",
        ws_max_size=4 * ctx.settings.max_frame_bytes,
        ws=preauth_capped_ws(ctx.preauth_max_bytes),
        http=guarded_h11(ConnectionLimits()),
        timeout_keep_alive=KEEP_ALIVE_S,
        lifespan="off",
        timeout_graceful_shutdown=2,
    )
    server = uvicorn.Server(config)
    task = asyncio.create_task(server.serve())
    try:
        while not server.started and not task.done():
            await asyncio.sleep(0.01)
        if started is not None and server.started:
            started()
        await asyncio.shield(task)
    finally:
        # On cancellation let uvicorn shut down gracefully so its sockets are closed.
        server.should_exit = True
        with contextlib.suppress(Exception):
            await task
