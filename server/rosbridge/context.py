"""What every rosbridge connection of one server shares: graph, security, settings, caches."""

from __future__ import annotations

import asyncio
import collections
import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from server.graph import Graph
from server.http.security import Role, Security
from server.http.ws_guard import PREAUTH_MAX_BYTES
from server.rosbridge.budget import DecodeBudget
from server.rosbridge.decoder import Backend, InboundDecoder
from server.rosbridge.protocol import OFFLOAD_BINARY_BYTES, OFFLOAD_TEXT_BYTES
from server.rosbridge.values import to_json_text
from server.settings import Settings


class JsonCache:
    """JSON text of messages being delivered right now, keyed by identity.

    The graph hands the same dict to every subscriber in one synchronous pass, so N clients
    cost one ``json.dumps``. The cache is emptied on the next loop iteration, so a publisher
    that reuses and mutates one dict is never served stale text; each entry keeps its message
    alive, so an ``id`` cannot be reused while cached.
    """

    def __init__(self, size: int = 256) -> None:
        self._size = size
        self._entries: collections.OrderedDict[int, tuple[Any, str]] = collections.OrderedDict()

    def text(self, msg: Any) -> str:
        key = id(msg)
        hit = self._entries.get(key)
        if hit is not None and hit[0] is msg:
            return hit[1]
        text = to_json_text(msg)
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # no loop, so no "delivery pass" to scope the cache to
            return text
        if not self._entries:
            loop.call_soon(self._entries.clear)
        self._entries[key] = (msg, text)
        if len(self._entries) > self._size:
            self._entries.popitem(last=False)
        return text


@dataclass
class BridgeContext:
    """Shared by the connections of one server; build one per app (see ``make_router``).

    Attributes:
        service_timeout_s: default timeout of a ``call_service`` that names none (a client that
            provides a service and never answers must not hold the caller forever).
        out_queue_frames / out_queue_bytes: bound of a connection's outgoing queue; beyond it
            the oldest frames are dropped.
        stall_close_s: a client that has not read for this long while frames wait is closed
            with code 1008.
        auth_timeout_s: a connection without a token must send ``auth`` within this time.
        preauth_max_bytes: the largest frame a connection may send before it authenticates
            (an ``auth`` frame is ~100 bytes; 16 MB frames before auth would starve the auth
            deadline, one PNG frame would freeze the loop). Under ``serve`` the transport refuses
            a larger one at its frame header (``server.http.ws_guard``); the endpoint's own check
            covers servers without that.
        offload_decode_bytes / offload_binary_bytes: text / binary frames (and reassembled
            fragment texts) larger than this are decoded by the worker pool ``decoder``, as is
            every png, so decoding them never holds the event loop the drones' safety shares.
        decode_budget: what decoding one frame may cost (pixels, bytes, values, work).
        decode_backend / decode_workers / decode_queue: the pool: ``process`` (measured: a
            thread holds the GIL through ``json.loads``) or ``thread``, its size, and how
            many frames it holds at once (more are refused with a status error).
        observer_max_frame_bytes: the largest frame an observer may send (it subscribes and
            calls read-only services: small frames); larger ones are refused unread.
        max_calls_in_flight: concurrent ``call_service`` per connection (an observer flooding
            ``/console/describe`` caused controller overruns); more get a failed response.
        byte_rate_per_s / byte_burst: a token bucket of received bytes per connection, besides
            the frame rate (a few huge frames are as heavy as many small ones).
        max_connections_per_ip / max_connections_per_token: open WebSockets; beyond them a new
            one is refused at the handshake (20 200 half-open connections exhausted the file
            handles). Counts live in ``connections``.
    """

    graph: Graph
    security: Security
    settings: Settings
    service_timeout_s: float = 10.0
    out_queue_frames: int = 1000
    out_queue_bytes: int = 64 * 1024 * 1024
    stall_close_s: float = 10.0
    auth_timeout_s: float = 5.0
    preauth_max_bytes: int = PREAUTH_MAX_BYTES
    offload_decode_bytes: int = OFFLOAD_TEXT_BYTES
    offload_binary_bytes: int = OFFLOAD_BINARY_BYTES
    decode_budget: DecodeBudget = field(default_factory=DecodeBudget)
    decode_backend: Backend = "process"
    decode_workers: int = 2
    decode_queue: int = 4
    observer_max_frame_bytes: int = 64 * 1024
    max_calls_in_flight: int = 8
    byte_rate_per_s: float = 16 * 1024 * 1024
    byte_burst: float = 64 * 1024 * 1024
    max_connections_per_ip: int = 128
    max_connections_per_token: int = 128
    connections: collections.Counter[str] = field(default_factory=collections.Counter)
    clock: Callable[[], float] = time.monotonic
    wall_clock: Callable[[], float] = time.time
    json_cache: JsonCache = field(default_factory=JsonCache)
    # service type -> request field names in order, to map list ``args`` (rosapi fills this)
    request_fields: dict[str, tuple[str, ...]] = field(default_factory=dict)
    # intent/outcome rows for /ardrone/* commands (server.http.audit_trail.AuditTrail), if any
    audit: Any = None
    _conn_ids: itertools.count[int] = field(default_factory=lambda: itertools.count(1))
    _decoder: InboundDecoder | None = field(default=None, repr=False)

    @property
    def decoder(self) -> InboundDecoder:
        """The worker pool for expensive frames, made on first use from the fields above (its
        workers start with the first frame it is given)."""
        if self._decoder is None:
            self._decoder = InboundDecoder(
                self.decode_budget,
                self.settings.max_frame_bytes,
                workers=self.decode_workers,
                max_pending=self.decode_queue,
                backend=self.decode_backend,
            )
        return self._decoder

    def frame_limit(self, role: Role) -> int | None:
        """The transport's frame limit for a connection of ``role`` once authenticated: an
        observer's, or None (the transport's own, 4 × ``max_frame_bytes`` so that the
        endpoint can answer a frame over its limit with a status)."""
        return self.observer_max_frame_bytes if role is Role.OBSERVER else None

    def close(self) -> None:
        """Stop what the connections share (the decoder's workers)."""
        if self._decoder is not None:
            self._decoder.close()

    def new_owner(self, peer: str) -> str:
        """A graph owner name for a new connection (shown by rosapi/nodes)."""
        return f"/rosbridge/client_{next(self._conn_ids)}@{peer}"
