"""A vehicle process's commanded side on the bus (docs/bus.md): its ``cmd`` queryable answered by
the vehicle's own control ops, its status at 1 Hz and its camera, and the consoles it hears.

The camera goes out frame by frame as the vehicle node publishes it (up to its ``image_hz``),
the JPEG's bytes with its stamp as the attachment, dropped rather than queued under congestion.

The ops are those of the vehicle's control service (:meth:`VehicleHost._control`): ``direct``,
the task ops ``submit``, ``preempt`` and ``cancel`` (what a console's dialog understood, as
typed commands), ``telemetry``, ``truth``, ``fault``, and ``jog`` (its ``/cmd_vel``); each
command is judged first by the vehicle's own pilot lease
(:class:`~drone.bus.lease.VehicleLease`), one lease for every console.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zenoh

from drone.bus import keys
from drone.bus.commanded import CommandedVehicle, CommandRefused, ConsolePresence
from drone.bus.commands import Command
from drone.bus.lease import VehicleLease
from drone.bus.payloads import Status
from server.rosbridge.values import to_json_text
from server.vehicles.errors import VehicleError

if TYPE_CHECKING:
    from drone.bus.vehicle import VehicleBus
    from server.vehicles.host import VehicleHost
    from server.vehicles.spec import TopicSpec

log = logging.getLogger("uav_console.vehicle")

STATUS_PERIOD_S = 1.0
LATCHED_AGAIN_S = 2.0
CAMERA_TOPIC = "/ardrone/image_raw/compressed"
ALARM_HOLD_S = 10.0  # an alarm stays in the status this long after the supervisor said it
TOPIC_ACTIONS = ("takeoff", "land", "reset")  # the AR.Drone's /ardrone/<action> topics


class BusVehicleSide:
    """See the module docstring; ``step(now)`` from the host's periodic loop."""

    def __init__(self, host: VehicleHost, bus: VehicleBus, topics: tuple[TopicSpec, ...]) -> None:
        from server.vehicles import names

        assert bus.session is not None
        self.host = host
        self.name = host.name
        self.lease = VehicleLease()
        self.commanded = CommandedVehicle(
            bus.session,
            bus.fleet,
            bus.name,
            self._command,
            self.lease,
            asyncio.get_running_loop(),
        )
        loop = asyncio.get_running_loop()
        self.presence = ConsolePresence(
            bus.session,
            bus.fleet,
            time.monotonic,
            # a console's clock, from its beat (command deadlines)
            on_beat=lambda sent: loop.call_soon_threadsafe(
                host.clock_offset.sample, sent, time.time()
            ),
        )
        # the consoles' beats also carry the id of the flight recording, for our audit rows
        self._recordings = bus.session.declare_subscriber(
            keys.all_console_heartbeats(bus.fleet),
            lambda sample: self._on_beat(sample, loop),
        )
        self._alarms: deque[tuple[float, str]] = deque(maxlen=20)
        self._alarm_sub = host.graph.subscribe(
            names.alarm_topic(host.name), self._on_alarm, type=names.STRING
        )
        self._next_status = 0.0
        self._next_latched = 0.0
        self.commanded.start()
        self.camera_topics = [t for t in topics if t.name.endswith(CAMERA_TOPIC)]
        self._camera_subs = [
            host.graph.subscribe(t.name, self._on_image, type=t.type, owner="bus")
            for t in self.camera_topics
        ]
        # the vehicle's own topics, for the consoles' graphs (the camera has its own key)
        self._mirrored = [t for t in topics if not t.name.endswith(CAMERA_TOPIC)]
        self._graph_pubs: dict[str, zenoh.Publisher] = {}
        self._graph_subs = []
        for topic in self._mirrored:
            self._graph_pubs[topic.name] = bus.session.declare_publisher(
                keys.graph(bus.fleet, bus.name, topic.name),
                congestion_control=zenoh.CongestionControl.DROP,
            )
            self._graph_subs.append(
                host.graph.subscribe(
                    topic.name, self._mirror(topic.name), type=topic.type, owner="bus"
                )
            )

    def _mirror(self, topic: str) -> Callable[[dict[str, Any]], None]:
        pub = self._graph_pubs[topic]

        def put(msg: dict[str, Any]) -> None:
            pub.put(to_json_text(msg))

        return put

    def _on_image(self, msg: dict[str, Any]) -> None:
        """A frame of the vehicle node's camera topic: on the bus at once, as it was encoded."""
        data = msg.get("data")
        if not isinstance(data, bytes | bytearray):
            return
        stamp = msg.get("header", {}).get("stamp", {})
        try:
            made = float(stamp["sec"]) + float(stamp["nanosec"]) / 1e9
        except (KeyError, TypeError, ValueError):
            made = time.time()
        self.commanded.publish_camera(bytes(data), made)

    def _on_beat(self, sample: zenoh.Sample, loop: asyncio.AbstractEventLoop) -> None:
        """A console's beat (Zenoh thread): the id of the flight recording it carries, if any,
        for the vehicle's audit rows."""
        try:
            recording = json.loads(sample.payload.to_bytes()).get("recording")
        except (ValueError, AttributeError):
            return
        if isinstance(recording, str) and len(recording) <= 128:
            loop.call_soon_threadsafe(setattr, self.host, "recording_id", recording)

    def _on_alarm(self, msg: dict[str, Any]) -> None:
        """A supervisor's alarm (``/NAME/vehicle/alarm``): in the status for a while."""
        try:
            text = str(json.loads(str(msg.get("data", ""))).get("text", ""))
        except (ValueError, AttributeError):
            return
        self._alarms.append((time.monotonic(), text))

    async def _command(self, command: Command) -> dict[str, Any]:
        """One command, through the vehicle's control ops; refusals with their reason."""
        if command.op == "jog":
            return self._jog(command)
        if command.op == "direct" and command.args.get("topic") is True:
            return self._topic(command)
        args: dict[str, Any] = {**command.args, "op": command.op}
        if command.issued is not None:
            args["issued"] = command.issued
        if command.op == "direct" and command.is_stop and args.get("id") is None:
            args["id"] = command.id  # a stop runs once per id, whichever road brings it
        try:
            out = await self.host._control(args)
        except VehicleError as exc:
            raise CommandRefused(str(exc)) from exc
        if isinstance(out.get("expired"), dict):  # a direct action or task op past its deadline
            raise CommandRefused(str(out.get("detail") or f"{command.op} expired"), out)
        return out

    def _jog(self, command: Command) -> dict[str, Any]:
        """A velocity for the vehicle node's ``/cmd_vel`` (jog limits, the operator watchdog
        and the deadline are its own), as a page's jog over rosbridge is."""
        twist = {
            part: {axis: float(command.args.get(part, {}).get(axis, 0.0)) for axis in "xyz"}
            for part in ("linear", "angular")
        }
        issued = self.host._issued_arg({"issued": command.issued})
        self.host.graph.publish(f"{self.host.options.prefix}/cmd_vel", twist, issued=issued)
        return {"accepted": True, "detail": "jog sent"}

    def _topic(self, command: Command) -> dict[str, Any]:
        """A pilot's ``/ardrone/takeoff``, ``land`` or ``reset`` message at a console
        (rosbridge), published on the vehicle node's own topic as it came: the node judges its
        deadline, says a refusal and audits it as a topic's."""
        action = command.action
        if action not in TOPIC_ACTIONS:
            raise CommandRefused(f"no control topic for {action!r} ({', '.join(TOPIC_ACTIONS)})")
        issued = self.host._issued_arg({"issued": command.issued})
        self.host.graph.publish(f"{self.host.options.prefix}/ardrone/{action}", {}, issued=issued)
        return {"accepted": True, "detail": f"{action} sent"}

    def step(self, now: float) -> None:
        """Publish the status when due, and the latched topics again every few seconds (a
        console that joined since has them too)."""
        if now >= self._next_status:
            self._next_status = now + STATUS_PERIOD_S
            self.commanded.publish_status(self.status(now))
        if now >= self._next_latched:
            self._next_latched = now + LATCHED_AGAIN_S
            for topic in self._mirrored:
                last = self.host.graph.latched(topic.name) if topic.latch else None
                if last is not None:
                    self._graph_pubs[topic.name].put(to_json_text(last))

    def status(self, now: float) -> Status:
        detail = self.host.telemetry()
        detail.pop("truth", None)
        task = detail.get("task")
        task_name = ""
        if isinstance(task, dict):
            task_name = str(task.get("name") or "")
        return Status(
            drone=self.name,
            stamp=time.time(),
            mode=str(detail.get("ctrl_state", "")),
            task=task_name,
            alarms=[text for t, text in self._alarms if now - t <= ALARM_HOLD_S],
            lease=self.lease.current(time.time()),
            simulated=self.host.stack.sim is not None,
            detail=detail,
        )

    def close(self) -> None:
        for sub in [*self._graph_subs, *self._camera_subs]:
            sub.close()
        for pub in self._graph_pubs.values():
            pub.undeclare()  # type: ignore[no-untyped-call]
        self._alarm_sub.close()
        self._recordings.undeclare()  # type: ignore[no-untyped-call]
        self.presence.close()
        self.commanded.close()
