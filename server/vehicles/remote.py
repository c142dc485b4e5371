"""A drone whose stack runs in a vehicle process, as the web process sees it.

:class:`RemoteDroneStack` answers everything the REST routes ask of a
:class:`~server.vehicles.stack.DroneStack` (telemetry, direct actions, the latest JPEG, ground
truth, faults) from what the vehicle publishes on the bus (``/NAME/vehicle/telemetry``, the
camera topic) and through its control service; the drone's dialog runs in this process
(:mod:`server.vehicles.console_dialog`) and hands the vehicle typed commands. Stops (land,
emergency) are sent and answered at once ("emergency sent"), as in-process; other direct
actions get the vehicle's own verdict (it checks them against its drone's state now, not
against telemetry 0.1 s old).

A vehicle that ``serve`` has just spawned (or restarted) takes a few seconds to join: calls made
meanwhile wait for it (:attr:`RemoteDroneStack.expected_until`, at most ``JOIN_WAIT_S``) instead
of failing; a vehicle that does not come raises :class:`VehicleUnavailable` (REST: 503). A spoken
or typed command waits less (``COMMAND_JOIN_WAIT_S``), and is not sent to a vehicle that is on
the bus but silent (no telemetry for ``SILENT_S``: stopped, stalled), where it would wait in a
socket buffer and act whenever the process came back; one that falls silent while the command
is being answered is not waited for either: 503 with ``Retry-After`` at once, the caller retries.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import logging
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, cast

from drone.deadline import Expired
from server.captioner.grounding import SeenMarker, bearing_deg
from server.graph import Graph, GraphError, NotFound, ServiceError
from server.vehicles import names
from server.vehicles.direct_actions import DirectOutcome
from server.vehicles.errors import RemoteCallError, VehicleUnavailable
from server.vehicles.stack import DroneStack
from server.vehicles.stops import StopVerdict

if TYPE_CHECKING:
    from drone.ardrone.driver import ARDroneDriver
    from drone.vehicle import Vehicle

log = logging.getLogger(__name__)

TELEMETRY_STALE_S = 1.0
CALL_TIMEOUT_S = 10.0
# How long a spawned or restarted vehicle process may take to join before calls to it fail
# (start-up is 2-5 s on a busy machine: imports, simulator, driver, perception).
JOIN_WAIT_S = 30.0
JOIN_POLL_S = 0.05
# What a command (``POST /command``, ``POST /speech``) waits for a starting vehicle, and how long
# a joined one may publish no telemetry (10 Hz) before it counts as unreachable.
COMMAND_JOIN_WAIT_S = 3.0
SILENT_S = 2.0
STOPS = ("land", "emergency", "hover")
# How long the dialog waits for the vehicle's telemetry of now before judging a sentence on
# the last periodic one (a stop the dialog cannot judge still goes: DialogManager._check).
REFRESH_TIMEOUT_S = 0.3
# How long a stop with an id (the page's, down the server road) waits for the vehicle's verdict
# before the answer says "sent, not confirmed" (the stop itself still goes: see act_stop).
STOP_CONFIRM_S = 2.0


class _Frames:
    """What ``Runtime.describe`` reads of a driver: the latest camera frame (from the JPEG)."""

    def __init__(self, stack: RemoteDroneStack) -> None:
        self._stack = stack

    @property
    def latest_frame(self) -> Any:
        import cv2
        import numpy as np

        _, jpeg = self._stack.latest_jpeg()
        if jpeg is None:
            return None
        return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)

    async def stop(self) -> None:
        """The vehicle process owns the driver."""


class _Remote:
    """Stand-in for parts that live in the vehicle process (stopping them is its job)."""

    async def stop(self, **_: Any) -> None:
        return None


class RemoteDroneStack(DroneStack):
    """See the module docstring; ``graph`` is the central graph."""

    def __init__(self, graph: Graph, name: str, prefix: str, *, simulated: bool = True) -> None:
        super().__init__(
            name,
            prefix,
            cast("Vehicle", _Remote()),
            cast("ARDroneDriver", None),
            sim=cast(Any, _Remote()) if simulated else None,
        )
        self.driver = cast("ARDroneDriver", _Frames(self))
        self.graph = graph
        self.info: dict[str, Any] = {}
        self.last: dict[str, Any] = {}
        self.last_t: float | None = None
        self._jpeg_data: bytes | bytearray | None = None
        self._jpeg: tuple[int, bytes | None] = (-1, None)
        self._jpeg_count = 0
        self._pending: set[asyncio.Task[Any]] = set()
        # monotonic time until which a vehicle that is not on the bus is expected to join
        # (set when ``serve`` spawns or restarts its process); None: not expected.
        self.expected_until: float | None = None
        # set by VehicleCentral: opens the flight recording and tells the vehicle its id
        self.touch_recording: Callable[[], None] | None = None
        self._subs = [
            graph.subscribe(names.telemetry_topic(name), self._on_telemetry, type=names.STRING),
            graph.subscribe(names.info_topic(name), self._on_info, type=names.STRING),
            graph.subscribe(
                f"{prefix}/ardrone/image_raw/compressed",
                self._on_image,
                type="sensor_msgs/CompressedImage",
            ),
        ]

    # ------------------------------------------------------------------ inputs
    def _on_telemetry(self, msg: dict[str, Any]) -> None:
        try:
            data = json.loads(str(msg.get("data", "")))
        except ValueError:
            log.warning("%s: bad telemetry message", self.name)
            return
        if isinstance(data, dict):
            self.last = data
            self.last_t = time.monotonic()

    def _on_info(self, msg: dict[str, Any]) -> None:
        try:
            data = json.loads(str(msg.get("data", "")))
        except ValueError:
            return
        if isinstance(data, dict):
            self.info = data
            if not data.get("simulated", True):
                self.sim = None

    def _on_image(self, msg: dict[str, Any]) -> None:
        """A frame of the drone's camera topic: its JPEG's bytes, as the graph carries
        ``uint8[]`` (the link's base64 was decoded by the rosbridge endpoint it came in by)."""
        data = msg.get("data")
        if isinstance(data, bytes | bytearray):
            self._jpeg_data = data
            self._jpeg_count += 1

    # ------------------------------------------------------------------ DroneStack
    @property
    def connected(self) -> bool:
        return self.last_t is not None and time.monotonic() - self.last_t < TELEMETRY_STALE_S

    def link_ok(self) -> bool:
        return self.connected and bool(self.last.get("link_ok"))

    def telemetry(self) -> dict[str, Any]:
        """The vehicle's telemetry: asked of it now from a worker thread (a sync REST route,
        so a read right after ``/sim/{id}/truth`` or an action is as fresh as in-process), else
        the last periodic one (≤ 0.1 s old). Before its first telemetry a starting vehicle
        is waited for; one that is gone answers with its last telemetry (the vehicle lost).

        Raises:
            VehicleUnavailable: nothing was ever heard from the vehicle and it did not join.
        """
        last, fresh_ok = self.last, False
        if self._off_loop() and (self.joined or not last):
            try:
                fresh = self._call_sync({"op": "telemetry"})
            except VehicleUnavailable:
                if not self.last:  # never heard from it: say so (503), not an empty drone
                    raise
            except (GraphError, RemoteCallError, TimeoutError) as exc:
                log.warning("%s: telemetry not answered (%s): the last one", self.name, exc)
            else:
                if isinstance(fresh, dict):
                    last, fresh_ok = fresh, True
        connected = fresh_ok or self.connected
        out = {k: v for k, v in last.items() if k != "truth"}
        out["link_ok"] = connected and bool(last.get("link_ok"))
        out["name"] = self.name
        out["simulated"] = self.sim is not None
        out["vehicle"] = {
            "mode": "process",
            "connected": connected,
            "pid": self.info.get("pid"),
            "door_url": self.info.get("door_url"),
            "age_s": None if self.last_t is None else round(time.monotonic() - self.last_t, 3),
        }
        return out

    async def refresh(self, timeout_s: float = REFRESH_TIMEOUT_S) -> bool:
        """Ask the vehicle for its telemetry now and keep it as the last (the periodic one
        may be up to a period old, more on a busy machine); False: not answered in time,
        the last one stays."""
        try:
            fresh = await asyncio.wait_for(self.call({"op": "telemetry"}, timeout_s), timeout_s)
        except (VehicleUnavailable, GraphError, RemoteCallError, TimeoutError) as exc:
            log.debug("%s: telemetry not refreshed (%s)", self.name, exc)
            return False
        if not isinstance(fresh, dict):
            return False
        self.last, self.last_t = {**self.last, **fresh}, time.monotonic()
        return True

    def direct(self, action: str) -> str:
        self._send({"op": "direct", "action": action})
        return f"{action} sent"

    async def act(self, action: str, battery_low_pct: float) -> tuple[bool, str]:
        """A direct action checked and done by the vehicle: (accepted, detail).

        Stops are sent and answered at once (they are never refused); anything else waits for
        the vehicle's verdict, which its dialog also says aloud when it refuses.

        Raises:
            VehicleUnavailable: the vehicle is not on the bus (a stop is sent all the same).
        """
        if action in STOPS:
            self.direct(action)
            return True, f"{action} sent"
        args = {"op": "direct", "action": action, "check": True}
        args["battery_low_pct"] = battery_low_pct
        try:
            out = await self.call(args)
        except VehicleUnavailable:
            raise
        except GraphError as exc:
            raise VehicleUnavailable(f"{self.name} did not take {action}: {exc}") from exc
        return bool(out.get("accepted", True)), str(out.get("detail", f"{action} sent"))

    async def act_in_time(
        self, action: str, battery_low_pct: float, issued: float | None
    ) -> DirectOutcome:
        """A motion action that carries when it was issued (console clock): the vehicle judges
        its deadline again as it receives it, then checks and does it, as :meth:`act`.

        Raises:
            VehicleUnavailable: the vehicle is not on the bus.
        """
        args: dict[str, Any] = {"op": "direct", "action": action, "check": True}
        args["battery_low_pct"] = battery_low_pct
        if issued is not None:
            args["issued"] = issued
        try:
            out = await self.call(args)
        except VehicleUnavailable:
            raise
        except GraphError as exc:
            raise VehicleUnavailable(f"{self.name} did not take {action}: {exc}") from exc
        late = out.get("expired")
        verdict = None
        if isinstance(late, dict):
            try:
                verdict = Expired(float(late["age_s"]), float(late["deadline_s"]))
            except (KeyError, TypeError, ValueError):
                log.warning("%s: bad expiry in the answer to %s: %r", self.name, action, late)
        accepted = bool(out.get("accepted", True)) and verdict is None
        return DirectOutcome(accepted, str(out.get("detail", f"{action} sent")), verdict)

    async def act_stop(self, action: str, stop_id: str, issued: float | None) -> StopVerdict:
        """A stop with the page's id: sent at once; the vehicle runs it unless its door brought
        it first (or it was superseded) and says which. Its answer is awaited
        ``STOP_CONFIRM_S``; after that the call goes on (up to ``CALL_TIMEOUT_S``) and this
        answers "sent, not confirmed" (``delivered`` None), so the page keeps trying.

        Raises:
            VehicleUnavailable: the vehicle is not on the bus (the stop is still sent).
        """
        args: dict[str, Any] = {"op": "direct", "action": action, "id": stop_id}
        args["issued"] = issued
        call = asyncio.ensure_future(self.call(args))
        self._pending.add(call)
        call.add_done_callback(self._pending.discard)
        call.add_done_callback(_log_stop_failure(self.name, action))
        try:
            out = await asyncio.wait_for(asyncio.shield(call), STOP_CONFIRM_S)
        except VehicleUnavailable:
            raise
        except (TimeoutError, GraphError, RemoteCallError) as exc:
            why = "no answer yet" if isinstance(exc, TimeoutError) else str(exc)
            return StopVerdict(
                False,
                True,
                f"{action} sent to {self.name}; not confirmed ({why})",
                None,
                "server",
                None,
            )
        delivered = out.get("delivered")
        late = out.get("late_s")
        return StopVerdict(
            bool(out.get("ran", False)),
            bool(out.get("accepted", True)),
            str(out.get("detail", f"{action} sent")),
            float(delivered) if isinstance(delivered, int | float) else None,
            str(out.get("road", "server")),
            float(late) if isinstance(late, int | float) else None,
        )

    def seen_markers(self) -> list[SeenMarker]:
        """From the last telemetry (the snapshot's ``markers``, ≤ 0.1 s old)."""
        out: list[SeenMarker] = []
        for m in self.last.get("markers") or ():
            try:
                pose = (float(m["x"]), float(m["y"]), float(m["yaw_rad"]))
                mark = (float(m["marker_x"]), float(m["marker_y"]))
                out.append(SeenMarker(int(m["id"]), bearing_deg(*pose, *mark)))
            except (KeyError, TypeError, ValueError):
                continue
        return out

    def latest_jpeg(self) -> tuple[int, bytes | None]:
        if self._jpeg[0] != self._jpeg_count and self._jpeg_data is not None:
            self._jpeg = (self._jpeg_count, bytes(self._jpeg_data))
        return self._jpeg

    def truth(self) -> dict[str, Any]:
        """The simulator's ground truth, asked of the vehicle now (from a worker thread, as the
        sync REST route runs); on the loop itself, the last telemetry's (≤ 0.1 s old)."""
        out: dict[str, Any] | None = None
        if self._off_loop():
            try:
                out = dict(self._call_sync({"op": "truth"}))
            except VehicleUnavailable:
                if not self.last.get("truth"):
                    raise
            except (GraphError, RemoteCallError, TimeoutError) as exc:
                log.warning("%s: truth not answered (%s): the last one", self.name, exc)
        if out is None:
            if not self.last.get("truth"):
                raise VehicleUnavailable(f"{self.name} has sent no ground truth yet")
            out = dict(self.last["truth"])
        out["name"] = self.name
        return out

    def inject_fault(self, body: Any) -> None:
        """Apply a simulator fault in the vehicle (raises ``ValueError`` if it refuses)."""
        args: dict[str, Any] = {"op": "fault", "kind": body.kind}
        for key in ("duration_s", "battery_pct", "drain_pct_s"):
            value = getattr(body, key, None)
            if value is not None:
                args[key] = float(value)
        if getattr(body, "wind_mps", None) is not None:
            args["wind_mps"] = [float(v) for v in body.wind_mps]
        if not self._off_loop():
            self._send(args)
            return
        try:
            self._call_sync(args)
        except ServiceError as exc:
            raise ValueError(str(exc).split(" failed: ", 1)[-1]) from exc

    def _off_loop(self) -> bool:
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return self.graph.loop is not None
        return False

    def _call_sync(self, args: dict[str, Any], timeout_s: float = 5.0) -> Any:
        """Call the control service from a worker thread and wait for the answer (and, while
        the vehicle is expected to join, for the vehicle)."""
        assert self.graph.loop is not None
        fut = asyncio.run_coroutine_threadsafe(self.call(args, timeout_s), self.graph.loop)
        try:
            return fut.result(timeout_s + self._join_wait_left() + 1.0)
        except concurrent.futures.TimeoutError as exc:
            fut.cancel()
            raise TimeoutError(f"{self.name} did not answer") from exc

    # ------------------------------------------------------------------ calls
    @property
    def joined(self) -> bool:
        """Whether the vehicle's control service is on the graph (a bus drone: its liveliness)."""
        return self.graph.service_type(names.control_service(self.name)) is not None

    def expect(self, wait_s: float = JOIN_WAIT_S) -> None:
        """The vehicle process was (re)started: calls wait up to ``wait_s`` for it to join
        (and the old process's telemetry no longer says how long the new one is silent)."""
        self.expected_until = time.monotonic() + wait_s
        self.last_t = None

    def _join_wait_left(self) -> float:
        if self.expected_until is None:
            return 0.0
        return max(0.0, self.expected_until - time.monotonic())

    def _unavailable(self, why: str) -> VehicleUnavailable:
        return VehicleUnavailable(f"{self.name}'s flight process {why}", drone=self.name)

    async def wait_joined(self, max_wait_s: float | None = None) -> None:
        """Return once the vehicle is on the bus; wait while it is expected to join (at most
        ``max_wait_s`` when given).

        Raises:
            VehicleUnavailable: it is not there and not expected, or did not join in time.
        """
        end = time.monotonic() + (math.inf if max_wait_s is None else max_wait_s)
        while not self.joined:
            if self._join_wait_left() <= 0.0 or time.monotonic() >= end:
                if self.expected_until is not None:
                    raise self._unavailable(
                        "has not joined the server yet (it is starting); try again in a moment"
                    )
                raise self._unavailable("is not connected")
            await asyncio.sleep(JOIN_POLL_S)
        self.expected_until = None

    def silent_for(self) -> float:
        """Seconds since the vehicle's last telemetry (0 before the first: it has just
        joined, or the web process has just started)."""
        return 0.0 if self.last_t is None else time.monotonic() - self.last_t

    async def call(
        self,
        args: dict[str, Any],
        timeout_s: float = CALL_TIMEOUT_S,
        *,
        join_wait_s: float | None = None,
        silent_s: float | None = None,
    ) -> Any:
        """Call the vehicle's control service, once it has joined (see :meth:`wait_joined`,
        ``join_wait_s`` its longest wait). With ``silent_s``, a vehicle whose telemetry has
        stopped that long is not called, and the call is given up if it stops meanwhile.

        Raises:
            VehicleUnavailable: the vehicle is not on the bus (or silent).
            GraphError: the call failed or was not answered in ``timeout_s``.
        """
        await self.wait_joined(join_wait_s)
        if silent_s is not None and self.silent_for() > silent_s:
            raise self._unavailable(
                f"is not answering (silent for {self.silent_for():.1f} s); nothing was sent"
            )
        coro = self.graph.call_service(names.control_service(self.name), args, timeout=timeout_s)
        try:
            if silent_s is None:
                return await coro
            return await self._unless_silent(coro, silent_s)
        except NotFound as exc:  # it left between the check and the call
            raise self._unavailable("is not connected") from exc

    async def _unless_silent(self, coro: Any, silent_s: float) -> Any:
        """Await ``coro``, or give it up once the vehicle's telemetry stops for ``silent_s``."""
        call = asyncio.ensure_future(coro)
        polled = time.monotonic()
        try:
            while True:
                done, _ = await asyncio.wait({call}, timeout=0.1)
                if done:
                    return call.result()
                # Our own loop stalled (a burst of untrusted input): the telemetry may be
                # waiting on the bus; judge the vehicle on the next round.
                stalled, polled = time.monotonic() - polled > 0.5, time.monotonic()
                if not stalled and self.silent_for() > silent_s:
                    raise self._unavailable(
                        f"stopped answering (silent for {self.silent_for():.1f} s); the "
                        "command was sent and may still be carried out if the process recovers"
                    )
        finally:
            call.cancel()

    def _send(self, args: dict[str, Any]) -> None:
        """Send without waiting, from the loop or from a worker thread (sync REST routes)."""

        async def send() -> None:
            try:
                await self.call(args)
            except (GraphError, RemoteCallError) as exc:
                log.error("%s: %s not delivered: %s", self.name, args.get("op"), exc)

        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            loop = None
        if loop is None:
            target = self.graph.loop
            if target is None:
                raise RuntimeError("the graph has no event loop yet")
            asyncio.run_coroutine_threadsafe(send(), target)
            return
        task = loop.create_task(send())
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self._subs = []


def _log_stop_failure(name: str, action: str) -> Callable[[asyncio.Future[Any]], None]:
    def done(fut: asyncio.Future[Any]) -> None:
        if not fut.cancelled() and fut.exception() is not None:
            log.error("%s: %s not delivered: %s", name, action, fut.exception())

    return done
