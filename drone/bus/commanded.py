"""A vehicle's commanded side of the bus: it answers ``…/cmd`` queries and publishes its status
(1 Hz) and camera (JPEG, dropped rather than queued).

Each query is decoded (:mod:`drone.bus.commands`), judged by the vehicle's own pilot lease
(:mod:`drone.bus.lease`) and answered exactly once: accepted with the op's result, or refused
with the reason (malformed, unknown op, the lease, the handler's own refusal: a deadline
passed, a drone that cannot take off). Refusals are logged with their reason.

Order: commands run one at a time in the order they came, on the vehicle's event loop. Stops
(land, hover, emergency), jogs (a stream of velocities, the newest wins) and reads never wait in
that queue: they run as they arrive, and a
stop answers every command still queued behind it "superseded", so nothing queued before a
stop flies after it; nor does a command its console issued before the stop that arrives after
it (a stop travels at a higher priority and may overtake it).

Zenoh calls back on its own threads; everything here past the decode runs on the loop.
"""

from __future__ import annotations

import asyncio
import collections
import json
import logging
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

import zenoh

from drone.bus import keys
from drone.bus.commands import (
    READ_OPS,
    Command,
    CommandReply,
    decode_command,
    encode_reply,
    id_of,
    refusal,
)
from drone.bus.errors import PayloadError
from drone.bus.lease import VehicleLease
from drone.bus.payloads import Status, encode, encode_camera_stamp

log = logging.getLogger(__name__)


class CommandRefused(Exception):
    """Raised by a command handler: the vehicle will not do it; the message says why, and
    ``result`` carries what the op found (an expired command's age and deadline)."""

    def __init__(self, reason: str, result: dict[str, Any] | None = None) -> None:
        super().__init__(reason)
        self.result = dict(result or {})


Handler = Callable[[Command], Awaitable[dict[str, Any]]]


class CommandedVehicle:
    """See the module docstring.

    Args:
        session: the vehicle's Zenoh session (user ``vehicle-NAME``).
        fleet, name: its keys' segments.
        handler: runs one command, returns its result (raises :class:`CommandRefused`).
        lease: the vehicle's pilot lease.
        loop: the event loop the handler runs on.
        clock: Unix seconds (lease times).
    """

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        name: str,
        handler: Handler,
        lease: VehicleLease,
        loop: asyncio.AbstractEventLoop,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.session = session
        self.fleet = keys.segment(fleet)
        self.name = keys.segment(name)
        self.handler = handler
        self.lease = lease
        self.loop = loop
        self.clock = clock
        self.refused: list[str] = []  # reasons, newest last (at most 50)
        self.answered = 0
        self._queue: collections.deque[tuple[zenoh.Query, Command]] = collections.deque()
        # console → the ``issued`` of its latest stop (its clock): what it issued before that
        # and arrives after (a stop goes at a higher priority and may overtake) is not done
        self._stopped: dict[str, float] = {}
        self._wake = asyncio.Event()
        self._tasks: set[asyncio.Task[None]] = set()
        self._worker: asyncio.Task[None] | None = None
        self._queryable: Any = None
        self._status: zenoh.Publisher | None = None
        self._camera: zenoh.Publisher | None = None

    def start(self) -> None:
        """Declare the queryable and the publishers; start the command worker (on the loop)."""
        self._worker = self.loop.create_task(self._work(), name=f"bus-commands:{self.name}")
        self._queryable = self.session.declare_queryable(
            keys.command(self.fleet, self.name), self._on_query
        )
        self._status = self.session.declare_publisher(
            keys.status(self.fleet, self.name), congestion_control=zenoh.CongestionControl.DROP
        )
        self._camera = self.session.declare_publisher(
            keys.camera(self.fleet, self.name),
            congestion_control=zenoh.CongestionControl.DROP,
            express=True,
            priority=zenoh.Priority.DATA_LOW,
        )

    # ------------------------------------------------------------------ publications
    def publish_status(self, status: Status) -> None:
        if self._status is not None:
            self._status.put(encode(status))

    def publish_camera(self, jpeg: bytes, stamp: float | None = None) -> None:
        """One JPEG frame; ``stamp``: when it was made (Unix seconds), as its attachment."""
        if self._camera is not None:
            attachment = encode_camera_stamp(stamp) if stamp is not None else None
            self._camera.put(jpeg, attachment=attachment)

    # ------------------------------------------------------------------ queries (Zenoh thread)
    def _on_query(self, query: zenoh.Query) -> None:
        data = query.payload.to_bytes() if query.payload is not None else b""
        try:
            command = decode_command(data)
        except PayloadError as exc:
            self._refuse(query, id_of(data), f"malformed command: {exc}")
            return
        self.loop.call_soon_threadsafe(self._accept, query, command)

    # ------------------------------------------------------------------ the loop
    def _accept(self, query: zenoh.Query, command: Command) -> None:
        verdict = self.lease.judge(command, self.clock())
        if not verdict.allowed:
            self._refuse(query, command.id, verdict.reason, command)
            return
        if command.is_stop and command.issued is not None:
            last = self._stopped.get(command.console, command.issued)
            self._stopped[command.console] = max(last, command.issued)
        elif self._before_stop(command):
            self._refuse(query, command.id, "superseded by a stop issued after it", command)
            return
        if command.is_stop:
            for queued_query, queued in self._queue:
                self._refuse(
                    queued_query,
                    queued.id,
                    f"superseded by {command.action} before it ran",
                    queued,
                )
            self._queue.clear()
        if command.is_stop or command.op in READ_OPS or command.op in ("lease", "jog"):
            task = self.loop.create_task(self._run(query, command))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
            return
        self._queue.append((query, command))
        self._wake.set()

    def _before_stop(self, command: Command) -> bool:
        """A command that moves the drone, issued before its console's latest stop."""
        if command.op in READ_OPS or command.op == "lease" or command.issued is None:
            return False
        stopped = self._stopped.get(command.console)
        return stopped is not None and command.issued <= stopped

    async def _work(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._queue:
                query, command = self._queue.popleft()
                await self._run(query, command)

    async def _run(self, query: zenoh.Query, command: Command) -> None:
        try:
            if command.op == "lease":
                result: dict[str, Any] = {"holder": self.lease.current(self.clock())}
            else:
                result = await self.handler(command)
        except CommandRefused as exc:
            self._refuse(query, command.id, str(exc), command, exc.result)
            return
        except Exception as exc:  # the handler failed: said to the sender, never a hang
            log.exception("%s: %s %s failed", self.name, command.op, command.id)
            self._refuse(query, command.id, f"{command.op} failed: {exc}", command)
            return
        self._reply(
            query, CommandReply(id=command.id, drone=self.name, accepted=True, result=result)
        )

    def _refuse(
        self,
        query: zenoh.Query,
        command_id: str,
        reason: str,
        command: Command | None = None,
        result: dict[str, Any] | None = None,
    ) -> None:
        who = f" from {command.holder}" if command is not None else ""
        what = f"{command.op} {command.action or ''}".strip() if command is not None else "command"
        log.warning("%s: %s%s refused: %s", self.name, what, who, reason)
        self.refused.append(reason)
        del self.refused[:-50]
        self._reply(query, refusal(command_id, self.name, reason, result))

    def _reply(self, query: zenoh.Query, reply: CommandReply) -> None:
        try:
            query.reply(keys.command(self.fleet, self.name), encode_reply(reply))
            self.answered += 1
        except zenoh.ZError as exc:  # the querier gave up (timeout) or the session closed
            log.warning("%s: reply to %s not sent: %s", self.name, reply.id, exc)
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    def close(self) -> None:
        if self._worker is not None:
            self._worker.cancel()
        for task in list(self._tasks):
            task.cancel()
        for query, command in self._queue:
            self._refuse(query, command.id, "the vehicle is stopping", command)
        self._queue.clear()
        for decl in (self._queryable, self._status, self._camera):
            if decl is not None:
                decl.undeclare()
        self._queryable = self._status = self._camera = None


class ConsolePresence:
    """The consoles a vehicle hears on the bus: their liveliness (which are there) and their
    10 Hz heartbeat (when one was last heard: a stalled console stops beating at once, its
    liveliness lasts until Zenoh's lease on its link runs out).

    ``on_beat(console_time)`` is called (on a Zenoh thread) with each beat's Unix time."""

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        clock: Callable[[], float],
        on_beat: Callable[[float], object] | None = None,
    ) -> None:
        self.clock = clock
        self.on_beat = on_beat
        self._lock = threading.Lock()
        self._consoles: set[str] = set()
        self._last = clock()  # joined: counts as heard from now
        self._sub = session.liveliness().declare_subscriber(
            keys.all_consoles_alive(fleet), self._on_alive, history=True
        )
        self._beats = session.declare_subscriber(keys.all_console_heartbeats(fleet), self._on_beat)

    def _on_beat(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._last = self.clock()
        try:
            sent = json.loads(sample.payload.to_bytes())["t"]
        except (ValueError, KeyError, TypeError):
            return
        if self.on_beat is not None and isinstance(sent, int | float):
            self.on_beat(float(sent))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        name = keys.console_of(str(sample.key_expr))
        if name is None:
            return
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._consoles.add(name)
            else:
                self._consoles.discard(name)

    def consoles(self) -> list[str]:
        with self._lock:
            return sorted(self._consoles)

    def last_heard(self) -> float:
        """When a console's heartbeat last came (the start, before any)."""
        with self._lock:
            return self._last

    def close(self) -> None:
        self._sub.undeclare()  # type: ignore[no-untyped-call]
        self._beats.undeclare()  # type: ignore[no-untyped-call]
