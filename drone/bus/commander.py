"""A console's commanding side of the bus: commands as queries on ``…/cmd`` (one reply each),
and what the vehicles publish for it to show (status, camera).

I/O over a Zenoh session the console already has (a client of its router). Zenoh answers on
its own threads; :meth:`BusCommander.command` hands each reply to the caller's event loop.

While the console restarts its router (new vehicle keys, ``drone.bus.console``) it holds the
commands (:meth:`BusCommander.hold`): those in flight are answered first
(:meth:`BusCommander.drained`), new ones wait, and on :meth:`BusCommander.release` the stops
among them go first, then the rest in the order they came. One held longer than
:data:`HOLD_MAX_S` fails with :class:`~drone.bus.errors.NoReply` ("not sent"): a command is
never lost without its sender hearing of it.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import logging
import secrets
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
import zenoh.handlers

from drone.bus import keys
from drone.bus.commands import Command, CommandReply, decode_reply, encode_command
from drone.bus.errors import NoReply, PayloadError
from drone.bus.payloads import (
    Status,
    Telemetry,
    decode_camera_stamp,
    decode_status,
    decode_telemetry,
)

log = logging.getLogger(__name__)

COMMAND_TIMEOUT_S = 10.0
HOLD_MAX_S = 10.0  # a command held through a router restart longer than this is not sent
DRAIN_POLL_S = 0.01

StatusCallback = Callable[[Status], None]
TelemetryCallback = Callable[[Telemetry], None]
CameraCallback = Callable[[int, bytes, float | None], None]  # counter, JPEG, stamp


class BusCommander:
    """See the module docstring. ``console``: this console's name, one key segment (the lease
    holder's half; its presence on the bus is its session's token, ``drone.bus.console``)."""

    def __init__(self, session: zenoh.Session, fleet: str, console: str) -> None:
        self.session = session
        self.fleet = keys.segment(fleet)
        self.console = console
        self._ids = itertools.count(1)
        self._prefix = secrets.token_hex(4)
        self._lock = threading.Lock()
        self._status: dict[str, Status] = {}
        self._camera: dict[str, tuple[int, bytes]] = {}
        self.refused = 0  # status payloads that did not decode
        self._holding = False
        self._held: list[tuple[bool, asyncio.Future[None]]] = []  # (a stop, its go)
        self._in_flight = 0
        self._beat = session.declare_publisher(
            keys.console_heartbeat(self.fleet, console),
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.INTERACTIVE_HIGH,
            express=True,
        )
        self._watchers: dict[str, tuple[StatusCallback, TelemetryCallback, CameraCallback]] = {}
        self._subs: list[Any] = [
            session.declare_subscriber(keys.all_status(self.fleet), self._on_status),
            session.declare_subscriber(keys.all_camera(self.fleet), self._on_camera),
            session.declare_subscriber(keys.all_telemetry(self.fleet), self._on_telemetry),
        ]

    # ------------------------------------------------------------------ commands
    def new_command(
        self,
        drone: str,
        op: str,
        args: dict[str, Any] | None = None,
        *,
        pilot: str = "pilot",
        issued: float | None = None,
    ) -> Command:
        keys.command(self.fleet, drone)  # a name that cannot be a key is refused here
        return Command.model_validate(
            {
                "id": f"{self.console}:{self._prefix}:{next(self._ids)}",
                "op": op,
                "args": args or {},
                "issued": issued,
                "console": self.console,
                "pilot": pilot,
            }
        )

    async def command(
        self, drone: str, command: Command, timeout_s: float = COMMAND_TIMEOUT_S
    ) -> CommandReply:
        """Send ``command`` to ``drone`` and await its reply (accepted or refused).

        Stops go at real-time priority, express (never batched behind other messages).
        While held (:meth:`hold`), it waits for :meth:`release` (stops first).

        Raises:
            NoReply: no vehicle answered (none by that name, the router refused the query,
                or no answer within ``timeout_s``), or held over :data:`HOLD_MAX_S`.
        """
        loop = asyncio.get_running_loop()
        if self._holding:
            go: asyncio.Future[None] = loop.create_future()
            self._held.append((command.is_stop, go))
            try:
                await asyncio.wait_for(go, HOLD_MAX_S)
            except TimeoutError as exc:
                raise NoReply(
                    f"{command.op} to {drone} not sent: the bus was restarting for over "
                    f"{HOLD_MAX_S:g} s"
                ) from exc
        self._in_flight += 1
        try:
            return await self._command(loop, drone, command, timeout_s)
        finally:
            self._in_flight -= 1

    def hold(self) -> None:
        """Hold new commands until :meth:`release` (call on the commands' event loop)."""
        self._holding = True

    async def drained(self, timeout_s: float) -> bool:
        """Wait until no command is in flight (at most ``timeout_s``); whether none is."""
        end = time.monotonic() + timeout_s
        while self._in_flight and time.monotonic() < end:
            await asyncio.sleep(DRAIN_POLL_S)
        return not self._in_flight

    def release(self) -> None:
        """Let the held commands go: the stops first (each wakes, and sends, in this order)."""
        self._holding = False
        held, self._held = self._held, []
        for _stop, go in sorted(held, key=lambda h: not h[0]):  # stable: in order otherwise
            if not go.done():
                go.set_result(None)

    async def _command(
        self,
        loop: asyncio.AbstractEventLoop,
        drone: str,
        command: Command,
        timeout_s: float,
    ) -> CommandReply:
        done: asyncio.Future[CommandReply] = loop.create_future()

        def settle(result: CommandReply | Exception) -> None:
            if done.done():
                return
            if isinstance(result, Exception):
                done.set_exception(result)
            else:
                done.set_result(result)

        def on_reply(reply: zenoh.Reply) -> None:
            ok = reply.ok
            if ok is None:
                err = reply.err
                why = err.payload.to_string() if err is not None else "an error"
                loop.call_soon_threadsafe(settle, NoReply(f"{drone} answered {why}"))
                return
            try:
                answer = decode_reply(ok.payload.to_bytes())
            except PayloadError as exc:
                log.warning("bus: a reply from %s refused: %s", ok.key_expr, exc)
                return
            if answer.id == command.id and answer.drone == drone:
                loop.call_soon_threadsafe(settle, answer)

        def on_end() -> None:
            loop.call_soon_threadsafe(
                settle,
                NoReply(
                    f"{drone} did not answer {command.op} (not on the bus, not allowed to "
                    "command it, or no answer in time); nothing was done"
                ),
            )

        stop = command.is_stop
        self.session.get(
            keys.command(self.fleet, drone),
            zenoh.handlers.Callback(on_reply, on_end),
            payload=encode_command(command),
            timeout=timeout_s,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            priority=zenoh.Priority.REAL_TIME if stop else zenoh.Priority.INTERACTIVE_HIGH,
            express=stop,
        )
        try:
            return await asyncio.wait_for(done, timeout_s + 1.0)
        except TimeoutError as exc:
            raise NoReply(f"{drone} did not answer {command.op} in {timeout_s} s") from exc

    def beat(self, now: float, recording: str | None = None) -> None:
        """This console's heartbeat (call at 10 Hz): ``now`` is its Unix time, from which a
        vehicle learns the console's clock (command deadlines); ``recording``: the id of the
        flight recording the console writes (``""``: none), for the vehicles' audit rows."""
        body: dict[str, float | str] = {"t": now}
        if recording is not None:
            body["recording"] = recording
        self._beat.put(json.dumps(body))

    # ------------------------------------------------------------------ publications
    def status(self, drone: str) -> Status | None:
        with self._lock:
            return self._status.get(drone)

    def camera(self, drone: str) -> tuple[int, bytes | None]:
        """(frame counter, the latest JPEG) of ``drone``'s camera, (-1, None) before one."""
        with self._lock:
            return self._camera.get(drone, (-1, None))

    def watch(
        self,
        drone: str,
        on_status: StatusCallback,
        on_telemetry: TelemetryCallback,
        on_camera: CameraCallback,
    ) -> None:
        """Call these (on a Zenoh thread) with each status, telemetry and camera frame (its
        counter, JPEG and stamp: when the vehicle made it, None if it did not say) ``drone``
        publishes."""
        with self._lock:
            self._watchers[drone] = (on_status, on_telemetry, on_camera)

    def unwatch(self, drone: str) -> None:
        with self._lock:
            self._watchers.pop(drone, None)

    def _on_telemetry(self, sample: zenoh.Sample) -> None:
        """Telemetry for the watched drones (the console's bus already counts bad ones)."""
        drone = keys.drone_of(str(sample.key_expr))
        with self._lock:
            watcher = self._watchers.get(drone or "")
        if watcher is None:
            return
        try:
            telemetry = decode_telemetry(sample.payload.to_bytes())
        except PayloadError:
            return
        if telemetry.drone == drone:
            watcher[1](telemetry)

    def forget(self, drone: str) -> None:
        with self._lock:
            self._status.pop(drone, None)
            self._camera.pop(drone, None)

    def _on_status(self, sample: zenoh.Sample) -> None:
        drone = keys.drone_of(str(sample.key_expr))
        try:
            status = decode_status(sample.payload.to_bytes())
        except PayloadError as exc:
            self.refused += 1
            log.warning("bus: status on %s refused: %s", sample.key_expr, exc)
            return
        if drone is None or status.drone != drone:
            self.refused += 1
            log.warning("bus: status on %s names drone %r", sample.key_expr, status.drone)
            return
        with self._lock:
            self._status[drone] = status
            watcher = self._watchers.get(drone)
        if watcher is not None:
            watcher[0](status)

    def _on_camera(self, sample: zenoh.Sample) -> None:
        drone = keys.drone_of(str(sample.key_expr))
        if drone is None:
            return
        jpeg = sample.payload.to_bytes()
        if not jpeg.startswith(b"\xff\xd8"):
            self.refused += 1
            log.warning("bus: camera frame on %s is not a JPEG", sample.key_expr)
            return
        with self._lock:
            count = self._camera.get(drone, (-1, b""))[0] + 1
            self._camera[drone] = (count, jpeg)
            watcher = self._watchers.get(drone)
        if watcher is not None:
            attachment = sample.attachment
            stamp = decode_camera_stamp(attachment.to_bytes() if attachment is not None else None)
            watcher[2](count, jpeg, stamp)

    def close(self) -> None:
        self._beat.undeclare()  # type: ignore[no-untyped-call]
        for sub in self._subs:
            sub.undeclare()
        self._subs = []
