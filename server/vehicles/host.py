"""The vehicle process: one drone's flight-critical stack, joined to its consoles' bus.

``uav-console vehicle --bus-connect ENDPOINT --name NAME`` (``serve --vehicles process`` spawns
one per drone) runs, on its own event loop and its own graph: the simulator
(``--drone sim``) or the driver of a real drone, the vehicle (EKF, 100 Hz controller thread,
perception), the task manager, the vehicle node (navdata, camera, pose, markers, task, jog,
operator watchdog), the supervisor (the ANS monitors), the fleet's LTM, and the safety door;
nothing of the web stack, the NLU or the dialog (tests/isolation/test_lean_vehicle.py). The
console runs this drone's dialog: it understands what the operator says and hands the task
manager typed commands (:mod:`server.vehicles.task_ops`), and it says the supervisor's alarms.
:class:`~server.vehicles.bus_vehicle.BusVehicleSide` answers the consoles' commands on the bus
and publishes the drone's status, camera and graph topics there, so a console and its clients
see the drone exactly as an in-process one. It joins the bus as ``vehicle-NAME`` with the
vehicle's own key (``--key-file`` or ``UAVC_VEHICLE_KEY``: :mod:`server.vehicles.keys`), never
the pilot token; the bus lets it publish only under its own name.

The drone stays safe without a console: :class:`CentralWatch` hovers it after
``heartbeat_timeout_s`` without a console's heartbeat on the bus and lands it after
``central_loss_land_s``; a router that is not up when the vehicle starts is joined when it is
(:meth:`drone.bus.vehicle.VehicleBus.join_later`), and Zenoh rejoins a router that comes back on
its endpoint. ``emergency``, ``land`` and ``hover`` also reach the drone through the safety door
(:mod:`server.vehicles.door`), the page's standing connection that no web traffic can delay;
each stop id runs once, whichever road brings it first (:meth:`deliver_stop`).

Deadlines (drone/deadline.py): a command from the central server carries when the operator
gave it, on the console's clock; the vehicle moves it onto its own clock with the offset it
learns from the console's heartbeat (:class:`~drone.deadline.ClockOffset`) and judges it again
as it receives it, so a command held up on the way (a stalled console) is not flown late.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import gc
import json
import logging
import os
import secrets
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

from drone.bus.config import vehicle_user
from drone.bus.errors import BusError
from drone.bus.probe import untrusted
from drone.bus.vehicle import VehicleBus
from drone.deadline import BadIssued, ClockOffset, Deadline, parse_issued
from drone.sim.errors import AddressInUse
from server.fleet.planner import FlightModel
from server.http.tls import TLSError, server_context
from server.settings import Settings
from server.timewarp import guard_s
from server.vehicles import names
from server.vehicles.bus_vehicle import BusVehicleSide
from server.vehicles.door import SafetyDoor, door_authenticator, loopback_origin, page_origin
from server.vehicles.door_protocol import (
    STOP_ACTIONS,
    Ack,
    Stop,
    Supersede,
    Superseded,
    stop_message,
)
from server.vehicles.errors import CannotStart, DoorProtocolError, VehicleError
from server.vehicles.relay import replies_out
from server.vehicles.spec import TopicSpec
from server.vehicles.task_ops import TASK_OPS, notice_message, run_task_op
from server.vehicles.watch import CentralWatch, LossAction

if TYPE_CHECKING:
    from drone.supervisor import Alarm
    from server.tasks.manager import TaskNotice
    from server.vehicles.direct_actions import DirectOutcome
    from server.vehicles.stops import StopVerdict

log = logging.getLogger("uav_console.vehicle")

TELEMETRY_PERIOD_S = 0.1
# GIL switch interval of a vehicle process. A thread that has waited this long for the GIL makes
# its holder hand it over, even the control thread spinning to its deadline, and then keeps it
# for up to as long: so it bounds how late a tick can start. CPython's 5 ms is half a control
# period; 0.5 ms gave a p99 period error of 0.50–0.59 ms, 0.1 ms 0.27 ms (bench/isolation.py).
VEHICLE_SWITCH_INTERVAL_S = 0.0001
WATCH_PERIOD_S = 0.05
# A vehicle whose parent ``serve`` is gone waits this long on the ground for a new one to adopt
# it before it exits (it never exits while flying).
ORPHAN_EXIT_S = 60.0


@dataclass(frozen=True)
class VehicleOptions:
    """What one vehicle process is (the rest comes from :class:`Settings`)."""

    name: str
    prefix: str  # "" for a single drone, "/uav2" in a fleet
    index: int = 0  # which simulator address and station
    safety_host: str = "127.0.0.1"
    safety_port: int = 0  # the safety door's port; 0: any free (announced in vehicle/info)
    safety_cert: Path | None = None  # with safety_key: the safety door speaks wss:
    safety_key: Path | None = None
    door_secret: bytes | None = None  # the console's key for door tickets (None: token only)
    parent_pid: int | None = None  # the supervising serve (None: a standalone vehicle)


def shared_topics(
    name: str, prefix: str, *, mavlink: bool = False, gps: bool = False
) -> tuple[TopicSpec, ...]:
    """The topics a whole vehicle shares with its consoles on the bus: an AR.Drone's navdata
    (and GPS navdata in a ``gps`` world) and camera, or a MAVLink drone's ``/mavros/*`` topics
    (no camera over MAVLink).

    All are its own drone's (a console shows no other: :func:`server.vehicles.central.
    bus_topics`); its task notices and alarms go out under ``/NAME/vehicle/*`` for the
    console's dialog, and what its nodes say on its ``/NAME/vehicle/reply``
    (:mod:`server.vehicles.relay`)."""
    from server.fleet.messages import STATUS_TOPIC, STATUS_TYPE
    from server.nodes.mavros_node import MAVROS_LATCHED, MAVROS_TOPICS
    from server.nodes.vehicle_node import IMAGE, MARKERS, NAVDATA, NAVDATA_GPS, POSE, TASK

    p = prefix
    if mavlink:
        drone: tuple[TopicSpec, ...] = tuple(
            TopicSpec(f"{p}{topic}", typ, latch=key in MAVROS_LATCHED)
            for key, (topic, typ) in MAVROS_TOPICS.items()
        )
    else:
        drone = (
            TopicSpec(f"{p}/ardrone/navdata", NAVDATA),
            *((TopicSpec(f"{p}/ardrone/navdata_gps", NAVDATA_GPS),) if gps else ()),
            TopicSpec(f"{p}/ardrone/image_raw/compressed", IMAGE),
        )
    return (
        *drone,
        TopicSpec(f"{p}/uav/pose", POSE),
        TopicSpec(f"{p}/uav/markers", MARKERS),
        TopicSpec(f"{p}/uav/task", TASK, latch=True),
        TopicSpec(names.task_event_topic(name), names.STRING),
        TopicSpec(names.reply_topic(name), "uav_console/Reply"),
        TopicSpec(f"/{name}/{STATUS_TOPIC}", STATUS_TYPE),
        TopicSpec(names.info_topic(name), names.STRING, latch=True),
        TopicSpec(names.telemetry_topic(name), names.STRING),
        TopicSpec(names.alarm_topic(name), names.STRING),
    )


class VehicleHost:
    """See the module docstring: ``await start()``, ``await run(stop)``, ``await stop()``."""

    def __init__(
        self, settings: Settings, options: VehicleOptions, key: str, *, safety_token: str | None
    ) -> None:
        """``key``: this vehicle's own key, its bus password (:mod:`server.vehicles.keys`);
        ``safety_token``: the pilot token the safety port checks (None: the port refuses all)."""
        self.settings = settings
        self.options = options
        self.key = key
        self.safety_token = safety_token
        self.name = options.name
        self.watch = CentralWatch(
            guard_s(settings.heartbeat_timeout_s),
            guard_s(max(settings.central_loss_land_s, settings.heartbeat_timeout_s + 0.1)),
        )
        self.loss_actions: list[str] = []
        self.bus: VehicleBus | None = None
        self.bus_side: BusVehicleSide | None = None
        self._tasks: list[asyncio.Task[Any]] = []
        self._started = time.monotonic()
        self.stop_requested = asyncio.Event()
        self.clock_offset = ClockOffset()  # the console's clock minus ours (heartbeat)

    async def start(self) -> None:
        from drone.sim.world import load_world
        from server.fleet.bus_ltm import BusLtmNode
        from server.fleet.geo import origin_of
        from server.fleet.ltm import LocalTaskManager
        from server.fleet.stations import station_positions
        from server.graph import Graph
        from server.store import AuditLog
        from server.vehicles.mavlink_stack import is_mavlink
        from server.vehicles.stack import build_drone_stack

        s, o = self.settings, self.options
        self.graph = Graph()
        self.graph.bind_loop(asyncio.get_running_loop())
        self.world = load_world(s.world)
        # As an in-process drone (server.runtime): jogs and /ardrone/* audited (the vehicle
        # writes to the server's audit log file; SQLite in WAL mode).
        self.audit = AuditLog(s.data_dir / "audit.db")
        self.mavlink = is_mavlink(s.drone)
        # The same stack the web process builds for an inline drone (server.runtime).
        self.stack = await build_drone_stack(
            self.name,
            o.prefix,
            o.index,
            s.drone,
            self.world,
            s,
            self.graph,
            self.audit,
            own_process=True,
        )
        vehicle, tasks = self.stack.vehicle, self.stack.tasks
        assert tasks is not None and self.stack.node is not None
        await self.stack.node.start()
        gps = getattr(self.world, "gps_origin", None) is not None
        topics = shared_topics(self.name, o.prefix, mavlink=self.mavlink, gps=gps)
        # audit rows carry the id of the consoles' flight recording (their bus heartbeats)
        self.recording_id = ""
        self.audit.recording = lambda: self.recording_id
        # what its nodes say (a late command, an autopilot's denial), under its own name
        self._replies_out = replies_out(self.graph, self.name)
        # the task manager's notices, for the console's dialog to follow and say
        self.graph.advertise(names.task_event_topic(self.name), names.STRING)
        loop = asyncio.get_running_loop()

        def notice(n: TaskNotice) -> None:  # from whichever thread gave it: out on the loop
            loop.call_soon_threadsafe(self._publish_task_event, notice_message(n, tasks))

        tasks.on_event(notice)
        pad = station_positions(self.world, o.index + 1)[-1]
        ltm = LocalTaskManager(
            self.name,
            vehicle,
            tasks,
            pad,
            origin=origin_of(self.world),
            ctm_timeout_s=s.central_grace_s,  # a drone on a plan flies on while no central
            model=FlightModel.for_flight_time(s.flight_time_s),
        )
        self.ltm = BusLtmNode(self.graph, ltm, clock=time.monotonic)
        self.graph.advertise_service(
            names.control_service(self.name), names.CONTROL_TYPE, self._control
        )
        self.graph.advertise(names.info_topic(self.name), names.STRING, latch=True)
        self.graph.advertise(names.telemetry_topic(self.name), names.STRING)
        console = {f"{scheme}://{s.host}:{s.port}" for scheme in ("http", "https")}
        allowed = console | set(s.allow_origins)
        tls = None
        if o.safety_cert is not None and o.safety_key is not None:
            try:
                tls = server_context(o.safety_cert, o.safety_key)
            except TLSError as exc:
                raise VehicleError(f"safety door: {exc}") from exc
        self.door = SafetyDoor(
            o.safety_host,
            o.safety_port,
            drone=self.name,
            authenticate=door_authenticator(
                # none given: nobody opens it with a token (tickets still work)
                self.safety_token or secrets.token_urlsafe(24),
                o.door_secret,
                self.name,
            ),
            on_stop=self._door_stop,
            on_supersede=self._door_supersede,
            status=self._door_status,
            # the console's page on whatever address the phone used (the token still decides)
            origin_allowed=lambda origin, host: (
                origin in allowed or loopback_origin(origin) or page_origin(origin, host, s.port)
            ),
            tls=tls,
        )
        try:
            await self.door.start()
        except OSError as exc:  # the port serve chose was taken meanwhile: any free one
            log.warning(
                "%s: safety door port %d: %s; on any free port", self.name, o.safety_port, exc
            )
            self.door.port = 0
            await self.door.start()
        self.bus = bus_for(s, self.name, self.key)
        if self.bus is None:
            raise VehicleError(f"{self.name}: no bus to join (--bus-connect ENDPOINT)")
        self._join_bus(self.bus, topics)
        self.graph.publish(names.info_topic(self.name), {"data": json.dumps(self.info())})
        supervisor = self.stack.supervisor
        assert supervisor is not None
        self.graph.advertise(names.alarm_topic(self.name), names.STRING)
        supervisor.on_alarm(self._publish_alarm)
        self._tasks = [
            asyncio.create_task(supervisor.run(vehicle.clock.now), name=f"ans:{self.name}"),
            asyncio.create_task(self._periodic(), name=f"vehicle-periodic:{self.name}"),
        ]

    def _join_bus(self, bus: VehicleBus, topics: tuple[TopicSpec, ...]) -> None:
        """Join the bus now, or, when its router is not up (yet: the vehicle may start first),
        as soon as it is; said in the log either way."""
        where = ", ".join(self.settings.bus_connect)
        try:
            bus.start()
        except BusError as exc:
            log.warning(
                "%s: the bus at %s is not up (%s); joining it when it is", self.name, where, exc
            )
            loop = asyncio.get_running_loop()
            bus.join_later(
                lambda: loop.call_soon_threadsafe(self._on_bus, bus, topics),
                lambda why: log.warning("%s: the bus at %s: %s", self.name, where, why),
            )
            return
        self._on_bus(bus, topics)

    def _on_bus(self, bus: VehicleBus, topics: tuple[TopicSpec, ...]) -> None:
        """Joined: answer commands, publish status, take plans from any central."""
        if bus.session is None or self.bus_side is not None:  # stopped meanwhile
            return
        log.info("%s: on the bus at %s", self.name, ", ".join(self.settings.bus_connect))
        self.bus_side = BusVehicleSide(self, bus, topics)
        self.ltm.join_bus(bus.session, self.settings.fleet_name)

    def _publish_alarm(self, alarm: Alarm) -> None:
        """Every alarm on ``/NAME/vehicle/alarm``: the console's dialog says it, and its
        clients and the flight recording see what the supervisor did and why."""
        msg = {"data": json.dumps(alarm.as_message(self.name))}
        self.graph.publish(names.alarm_topic(self.name), msg)

    def _publish_task_event(self, event: dict[str, Any]) -> None:
        self.graph.publish(names.task_event_topic(self.name), {"data": json.dumps(event)})

    def info(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "prefix": self.options.prefix,
            "simulated": self.stack.sim is not None,
            "door_url": self.door.url,
            "door_tickets": self.options.door_secret is not None,
            "pid": os.getpid(),
        }

    def direct(
        self, action: str, battery_low_pct: float | None = None, issued: float | None = None
    ) -> DirectOutcome:
        """A button, key or REST action: checked against the drone's state now and sent; one
        past its deadline (``issued`` on our clock) is not sent. The console's dialog says a
        refusal and the console writes the audit row."""
        from server.vehicles.direct_actions import perform

        low = self.settings.battery_low_pct if battery_low_pct is None else battery_low_pct
        return perform(
            self.stack,
            None,
            None,
            action,
            source="rest",
            battery_low_pct=low,
            issued=issued,
            deadline_s=self.settings.command_deadline_s,
        )

    def local_issued(self, issued: float) -> float:
        """A console-clock ``issued`` on our clock, never later than now."""
        return min(self.clock_offset.to_local(issued), time.time())

    def _issued_arg(self, args: dict[str, Any]) -> float | None:
        """A control call's ``issued`` on our clock (None: it has none, or one that is not
        Unix seconds, which is logged: a bad stamp must never hold a stop back)."""
        value = args.get("issued")
        if value is None:
            return None
        try:
            return self.local_issued(parse_issued(value))
        except BadIssued as exc:
            log.warning("%s: %s: no deadline judged here", self.name, exc)
            return None

    # ------------------------------------------------------------------ stops, both roads
    def deliver_stop(
        self, action: str, stop_id: str, issued: float | None, road: str
    ) -> StopVerdict:
        """A stop from either road (the door, or the console's ``direct`` with an ``id``):
        run once per id, never once superseded. A door stop is audited here (the console may
        be stopped); the console audits what it forwards."""
        from server.vehicles.direct_actions import perform_stop

        return perform_stop(
            self.stack,
            None,
            self.audit if road == "door" else None,
            action,
            stop_id,
            issued,
            road,
            source="door" if road == "door" else "rest",
            battery_low_pct=self.settings.battery_low_pct,
            now=time.time(),
        )

    def _door_stop(self, stop: Stop) -> Ack:
        v = self.deliver_stop(stop.action, stop.id, stop.issued, "door")
        return Ack(stop.id, stop.action, v.accepted, v.detail, v.delivered, v.road, v.late_s)

    def _door_supersede(self, msg: Supersede) -> Superseded:
        dropped, too_late = self.stack.stops.supersede(msg.ids, time.time())
        if dropped:
            log.info("%s: stops superseded before they arrived: %s", self.name, dropped)
        return Superseded(dropped, too_late)

    def _door_status(self) -> tuple[str, bool]:
        snap = self.stack.vehicle.snapshot()
        return str(snap.ctrl_state), bool(snap.link_ok)

    def _server_stop(self, action: str, args: dict[str, Any]) -> dict[str, Any]:
        try:
            stop = stop_message(action, args.get("id"), args.get("issued"))
        except DoorProtocolError as exc:
            raise VehicleError(str(exc)) from exc
        v = self.deliver_stop(action, stop.id, stop.issued, "server")
        return {
            "accepted": v.accepted,
            "detail": v.detail,
            "ran": v.run,
            "delivered": v.delivered,
            "road": v.road,
            "late_s": v.late_s,
        }

    async def _control(self, args: dict[str, Any]) -> dict[str, Any]:
        """``/NAME/vehicle/control`` (see :mod:`server.vehicles.names`)."""
        op = args.get("op")
        if op == "direct":
            action = str(args.get("action", ""))
            if action not in ("takeoff", "land", "hover", "emergency", "reset"):
                raise VehicleError(f"unknown action {action!r}")
            if action in STOP_ACTIONS and args.get("id") is not None:
                return self._server_stop(action, args)
            low = args.get("battery_low_pct")
            low_pct = float(low) if isinstance(low, int | float) else None
            out = self.direct(action, low_pct, self._issued_arg(args))
            answer: dict[str, Any] = {"accepted": out.accepted, "detail": out.detail}
            if out.expired is not None:
                late = {"age_s": out.expired.age_s, "deadline_s": out.expired.deadline_s}
                answer["expired"] = late
            return answer
        if op == "telemetry":
            return {k: v for k, v in self.telemetry().items() if k != "truth"}
        if op == "fault":
            if self.stack.sim is None:
                raise VehicleError(f"{self.name} is a real drone: no faults")
            wind = args.get("wind_mps")
            body = SimpleNamespace(
                kind=str(args.get("kind")),
                duration_s=args.get("duration_s"),
                battery_pct=args.get("battery_pct"),
                drain_pct_s=args.get("drain_pct_s"),
                wind_mps=tuple(wind) if isinstance(wind, list | tuple) else None,
            )
            try:
                self.stack.inject_fault(body)
            except ValueError as exc:
                raise VehicleError(str(exc)) from exc
            return {"applied": True}
        if op == "truth":
            if self.stack.sim is None:
                raise VehicleError(f"{self.name} is a real drone: no ground truth")
            return dict(self.stack.truth())
        if op in TASK_OPS:  # judged again here: a sentence held up on the way is not flown
            assert self.stack.tasks is not None
            return run_task_op(
                self.stack.tasks,
                str(op),
                args,
                issued=self._issued_arg(args),
                now=time.time(),
                deadline=Deadline(self.settings.command_deadline_s),
            )
        if op == "utterance":
            raise VehicleError(
                "this vehicle runs no dialog: its console understands sentences and sends "
                "typed commands (submit, preempt, cancel)"
            )
        raise VehicleError(
            f"unknown op {op!r} (direct, submit, preempt, cancel, fault, telemetry, truth)"
        )

    async def _periodic(self) -> None:
        """Telemetry at 10 Hz, the LTM at 5 Hz, the central-loss watch at 20 Hz."""
        next_telemetry = next_ltm = 0.0
        while True:
            now = time.monotonic()
            try:
                heard = self.heard()
                if self.ltm.flying_a_plan():  # the LTM's grace keeps it, not the console watch
                    heard = max(heard, now - self.settings.heartbeat_timeout_s / 2)
                action = self.watch.step(now, heard, bool(self.stack.vehicle.snapshot().flying))
                if action is not None:
                    self._on_loss(action, now - heard)
                if now >= next_telemetry:
                    next_telemetry = now + TELEMETRY_PERIOD_S
                    if self.bus is not None:
                        self.bus.publish(self.stack.vehicle.snapshot())
                    if self.bus_side is not None:
                        self.bus_side.step(now)
                    self.graph.publish(
                        names.telemetry_topic(self.name), {"data": json.dumps(self.telemetry())}
                    )
                if now >= next_ltm:
                    next_ltm = now + 0.2
                    self.ltm.step(now)
                    self._check_orphan(now, heard)
            except Exception:  # one bad round must not stop the watch
                log.exception("%s: periodic step failed", self.name)
            await asyncio.sleep(WATCH_PERIOD_S)

    def heard(self) -> float:
        """When a console was last heard from (monotonic): its heartbeat on the bus; the start
        counts as heard."""
        times = [self._started]
        if self.bus_side is not None:
            times.append(self.bus_side.presence.last_heard())
        return max(times)

    def telemetry(self) -> dict[str, Any]:
        from server.vehicles.stack import to_json_ready

        out = self.stack.telemetry()
        out["central_loss"] = {"losses": self.watch.losses, "actions": self.loss_actions[-10:]}
        if self.stack.sim is not None:
            out["truth"] = to_json_ready(self.stack.sim.truth)
        return out

    def _check_orphan(self, now: float, heard: float) -> None:
        """Parent ``serve`` gone (it crashed): wait on the ground for a new one to adopt us;
        give up after ``ORPHAN_EXIT_S`` of silence, never while flying."""
        parent = self.options.parent_pid
        if parent is None or os.getppid() == parent:
            return
        flying = bool(self.stack.vehicle.snapshot().flying)
        if not flying and now - heard > self.watch.land_after_s + ORPHAN_EXIT_S:
            log.warning("%s: supervisor gone and nobody adopted this vehicle: exiting", self.name)
            self.stop_requested.set()

    def _on_loss(self, action: LossAction, silent_s: float) -> None:
        self.loss_actions.append(action.value)
        log.warning("%s: central server silent for %.1f s: %s", self.name, silent_s, action.value)
        if self.stack.tasks is not None:
            self.stack.tasks.preempt(action.value, by="central server silent")

    async def run(self, stop: asyncio.Event) -> None:
        async def relay() -> None:
            await self.stop_requested.wait()
            stop.set()

        relay_task = asyncio.create_task(relay())
        try:
            await stop.wait()
        finally:
            relay_task.cancel()

    async def stop(self) -> None:
        for t in self._tasks:
            t.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        await self.door.stop()
        if self.bus_side is not None:
            self.bus_side.close()
        if self.bus is not None:
            self.bus.close()
        self._replies_out.close()
        self.ltm.close()
        st = self.stack
        if st.node is not None:
            await st.node.stop()
        with contextlib.suppress(Exception):
            await st.vehicle.stop(land=True)
        with contextlib.suppress(Exception):
            await st.driver.stop()
        if st.sim is not None:
            await st.sim.stop()
        self.audit.close()


def raise_priority(nice: int, rt_priority: int = 0) -> str:
    """Run the flight stack ahead of the web process on a busy CPU, where the OS permits it
    (root or CAP_SYS_NICE), else say so and go on; returns what was granted. Called before the
    process starts its threads, which inherit it (Linux: scheduling is per thread).

    ``rt_priority`` > 0: real-time round-robin (SCHED_RR) at that priority, below the control
    thread's SCHED_FIFO, so no normal task (the web process, a speech decoder, the captioner)
    can preempt a vehicle thread that holds the GIL or a lock the control thread needs next;
    with only a nice value (``vehicle_nice``, e.g. -10) a saturated CPU still could (bench/
    isolation.py: control-loop p99 1.39 ms, 15 overruns, with nice alone under speech decodes).
    """
    if rt_priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(rt_priority))
        except (OSError, AttributeError) as exc:
            log.info("vehicle keeps normal scheduling (SCHED_RR %d: %s)", rt_priority, exc)
        else:
            return f"SCHED_RR {rt_priority}"
    if nice >= os.getpriority(os.PRIO_PROCESS, 0):
        return f"nice {os.getpriority(os.PRIO_PROCESS, 0)}"
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except OSError as exc:
        log.info("vehicle priority unchanged (nice %d not permitted: %s)", nice, exc)
    return f"nice {os.getpriority(os.PRIO_PROCESS, 0)}"


def join_bus(settings: Settings, name: str, key: str) -> VehicleBus | None:
    """This vehicle on the fleet's bus (docs/bus.md) as ``vehicle-NAME`` with its own vehicle
    key, when told where the bus is; None when not, or when the router cannot be reached or
    refuses (said in the log)."""
    bus = bus_for(settings, name, key)
    if bus is None:
        return None
    try:
        bus.start()
    except BusError as exc:
        log.error("%s: not on the bus: %s", name, exc)
        return None
    log.info("%s: on the bus at %s", name, ", ".join(settings.bus_connect))
    return bus


def bus_for(settings: Settings, name: str, key: str) -> VehicleBus | None:
    """This vehicle's bus (not joined yet) as ``vehicle-NAME`` with its own vehicle key; None
    when not told where the bus is, or when a ``tls/`` router's CA is missing (logged)."""
    if not settings.bus_connect:
        return None
    ca = bus_ca(settings)
    if ca is not None and not ca.is_file():
        log.error(
            "%s: not on the bus: a tls/ router is verified with its console's CA, and %s is "
            "not a file (--bus-ca FILE: the console's DATA/tls/ca.pem)",
            name,
            ca,
        )
        return None
    return VehicleBus(
        settings.bus_connect,
        vehicle_user(name),
        key,
        settings.fleet_name,
        name,
        ca=str(ca) if ca is not None else None,
    )


def untrusted_router(settings: Settings) -> str | None:
    """Why a ``tls/`` router this vehicle is to join is not trusted by its CA (``bus_ca``): the
    reason, what to change; None when every router that answers is trusted (one not up yet is
    joined when it is)."""
    ca = bus_ca(settings)
    if ca is None or not ca.is_file():
        return None  # bus_for says what is missing
    for endpoint in settings.bus_connect:
        why = untrusted(endpoint, str(ca))
        if why is not None:
            return (
                f"the bus router at {endpoint} {why}; --bus-ca FILE: the console's DATA/tls/ca.pem"
            )
    return None


def bus_ca(settings: Settings) -> Path | None:
    """The CA file this vehicle verifies a ``tls/`` bus router with (None: no ``tls/`` router
    to join): ``bus_ca``, else the data directory's ``tls/ca.pem`` (the console's own)."""
    if not any(e.startswith("tls/") for e in settings.bus_connect):
        return None
    return settings.bus_ca or settings.data_dir / "tls" / "ca.pem"


async def run_vehicle(
    settings: Settings, options: VehicleOptions, key: str, *, safety_token: str | None
) -> None:
    """Run one vehicle process until SIGTERM/SIGINT (then land and stop)."""
    granted = raise_priority(settings.vehicle_nice, settings.vehicle_rt_priority)
    log.info("%s: vehicle threads run at %s", options.name, granted)
    # How long another thread may keep the GIL from the control thread (see the constant).
    sys.setswitchinterval(VEHICLE_SWITCH_INTERVAL_S)
    host = VehicleHost(settings, options, key, safety_token=safety_token)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    refusal = untrusted_router(settings)
    if refusal is not None:  # it would dial that router forever and never join
        raise CannotStart(f"{options.name}: {refusal}")
    try:
        await host.start()
    except OSError as exc:  # another console's simulator holds the address
        if not isinstance(exc, AddressInUse) and exc.errno != errno.EADDRINUSE:
            raise
        why = str(exc) if isinstance(exc, AddressInUse) else f"an address is in use ({exc})"
        raise CannotStart(
            f"{options.name}: {why} (another console's simulator?); `serve --sim-addr` moves "
            "this console's simulators"
        ) from None
    # Startup objects (modules, the world, the stack) out of the cyclic collector: a full
    # collection then walks only what the flight made since, so it cannot stall the control
    # thread as one over everything did (74 ms, vs 2.7 ms frozen, in bench/isolation.py).
    gc.freeze()
    log.info(
        "%s: %d startup objects frozen out of the garbage collector",
        options.name,
        gc.get_freeze_count(),
    )
    log.info("%s: vehicle up; safety door %s", options.name, host.door.url)
    pid_file = names.pid_dir(settings.data_dir, settings.port) / f"{options.name}.pid"
    with contextlib.suppress(OSError):  # lets a restarted serve find (and adopt) this vehicle
        pid_file.parent.mkdir(parents=True, exist_ok=True)
        pid_file.write_text(str(os.getpid()))
    try:
        await host.run(stop)
    finally:
        await host.stop()
        with contextlib.suppress(OSError):
            if pid_file.read_text() == str(os.getpid()):
                pid_file.unlink()
