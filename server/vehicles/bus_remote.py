"""A drone whose vehicle process is on the bus, as the console sees it (docs/bus.md).

:class:`BusDroneStack` is a :class:`~server.vehicles.remote.RemoteDroneStack` whose calls are
commands on the bus (queries on ``uavc/<fleet>/<drone>/cmd``, each answered accepted or refused
by the vehicle), whose presence is the vehicle's liveliness, and whose telemetry, status and
camera come from its publications. REST, the dialog and the buttons reach it exactly as they
reach any remote drone.

A refusal by the vehicle (its lease held by another pilot, a malformed or unknown command, a
deadline passed) comes back as the op's answer: ``accepted`` false and the vehicle's reason.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import zenoh

from drone.bus import keys
from drone.bus.errors import BusError, NoReply
from drone.bus.payloads import Status, Telemetry
from server.graph import GraphError, ServiceError
from server.msgs import header
from server.nodes.vehicle_node import EMPTY, IMAGE, TWIST
from server.vehicles.errors import RemoteCallError
from server.vehicles.remote import CALL_TIMEOUT_S, RemoteDroneStack
from server.vehicles.spec import TopicSpec

if TYPE_CHECKING:
    from drone.bus.commander import BusCommander
    from server.graph import Graph

log = logging.getLogger(__name__)

CAMERA_TOPIC = "/ardrone/image_raw/compressed"


class BusDroneStack(RemoteDroneStack):
    """See the module docstring.

    Args:
        alive: the drones alive on the bus now (the console's liveliness subscriber).
        pilot: who commands at this console now (the lease holder's half).
    """

    def __init__(
        self,
        graph: Graph,
        name: str,
        prefix: str,
        commander: BusCommander,
        alive: Callable[[], list[str]],
        pilot: Callable[[], str],
        *,
        topics: Mapping[str, TopicSpec] | None = None,
        simulated: bool = True,
    ) -> None:
        super().__init__(graph, name, prefix, simulated=simulated)
        self.commander = commander
        self._alive = alive
        self._pilot = pilot
        self._status: Status | None = None
        self.topics = dict(topics or {})  # what of its graph the vehicle may show here
        self.refused_topics: set[str] = set()
        self._advertised: set[str] = set()
        self._owner = f"bus:{name}"
        self._closed = False
        commander.watch(name, self._on_status, self._on_bus_telemetry, self._on_camera)
        self._mirror_sub = commander.session.declare_subscriber(
            keys.all_graph(commander.fleet, name), self._on_graph
        )
        self._pending_topics: set[asyncio.Task[Any]] = set()
        owner = f"bus:{name}"
        self._topic_subs = [
            graph.subscribe(f"{prefix}{topic}", self._forwarder(op, args), type=typ, owner=owner)
            for topic, typ, op, args in (
                ("/ardrone/takeoff", EMPTY, "direct", {"action": "takeoff"}),
                ("/ardrone/land", EMPTY, "direct", {"action": "land"}),
                ("/ardrone/reset", EMPTY, "direct", {"action": "reset"}),
                ("/cmd_vel", TWIST, "jog", {}),
            )
        ]

    # ------------------------------------------------------------------ rosbridge's topics
    def _forwarder(self, op: str, fixed: dict[str, Any]) -> Callable[..., None]:
        """A pilot's message on this drone's control topic (rosbridge): the same command on
        the bus, which the vehicle publishes on its own control topic (``topic``), so its node
        judges, says and audits it as the topic it was."""

        def forward(msg: dict[str, Any]) -> None:
            issued = self.graph.issued
            args = {**fixed, "topic": True}
            if op == "jog":
                args = {k: msg.get(k, {}) for k in ("linear", "angular")}
            if issued is not None:
                args["issued"] = issued
            self._spawn_command(op, args)

        return forward

    async def _topic_command(self, op: str, args: dict[str, Any]) -> None:
        try:
            out = await self.call({"op": op, **args}, join_wait_s=0.0)
        except (GraphError, RemoteCallError) as exc:
            log.warning("%s: %s from a control topic not delivered: %s", self.name, op, exc)
            return
        if isinstance(out, dict) and out.get("accepted") is False:
            log.warning("%s: %s refused: %s", self.name, op, out.get("detail"))

    # ------------------------------------------------------------------ publications
    def _on_status(self, status: Status) -> None:
        """1 Hz, on a Zenoh thread: the vehicle's own ``GET /drones/{id}`` answer."""
        self._status = status
        self.last = {**status.detail, **_fields(self.last)}
        if not status.simulated:
            self.sim = None

    def _on_bus_telemetry(self, telemetry: Telemetry) -> None:
        """10 Hz, on a Zenoh thread: position, state and battery over the last status."""
        base = dict(self._status.detail) if self._status is not None else dict(self.last)
        base.update(
            x=telemetry.x,
            y=telemetry.y,
            z=telemetry.z,
            yaw_deg=telemetry.yaw_deg,
            battery_pct=telemetry.battery_pct,
            ctrl_state=telemetry.state,
            link_ok=telemetry.link_ok,
            flying=telemetry.flying,
        )
        self.last = base
        self.last_t = time.monotonic()

    def _on_graph(self, sample: zenoh.Sample) -> None:
        """One of the vehicle's graph topics (Zenoh thread): onto this graph, if it is one the
        vehicle may publish (the router already made sure the vehicle is who it says)."""
        topic = keys.topic_of_graph(str(sample.key_expr))
        spec = self.topics.get(topic or "")
        if spec is None:
            if topic not in self.refused_topics:
                self.refused_topics.add(str(topic))
                log.warning(
                    "%s: its topic %s is not shown here (not one of its own)", self.name, topic
                )
            return
        try:
            msg = json.loads(sample.payload.to_bytes())
        except ValueError:
            log.warning("%s: %s is not JSON", self.name, topic)
            return
        if isinstance(msg, dict) and self.graph.loop is not None:
            self.graph.loop.call_soon_threadsafe(self._show, spec, msg)

    def _show(self, spec: TopicSpec, msg: dict[str, Any]) -> None:
        if self._closed:  # a message handed over as it closed
            return
        if spec.name not in self._advertised:
            self.graph.advertise(spec.name, spec.type, latch=spec.latch, owner=self._owner)
            self._advertised.add(spec.name)
        self.graph.publish(spec.name, msg)

    def _on_camera(self, count: int, jpeg: bytes, stamp: float | None) -> None:
        """A camera frame (Zenoh thread): the drone's image topic here, as its node sends it,
        stamped when the vehicle made it (else now), with the JPEG's bytes as they came (base64
        is made only for the rosbridge clients subscribed, once per frame:
        server/rosbridge/context.py ``JsonCache``); a frame is dropped on the way rather than
        queued behind others."""
        msg = {
            "header": header("ardrone_base_frontcam", time.time() if stamp is None else stamp),
            "format": "jpeg",
            "data": jpeg,
        }
        if self.graph.loop is not None:
            self.graph.loop.call_soon_threadsafe(self._show_camera, msg)

    def _show_camera(self, msg: dict[str, Any]) -> None:
        if self._closed:  # a frame handed over as it closed
            return
        topic = f"{self.prefix}{CAMERA_TOPIC}"
        if topic not in self._advertised:
            self.graph.advertise(topic, IMAGE, owner=self._owner)
            self._advertised.add(topic)
        self.graph.publish(topic, msg)

    def _spawn_command(self, op: str, args: dict[str, Any]) -> None:
        task = asyncio.get_running_loop().create_task(self._topic_command(op, args))
        self._pending_topics.add(task)
        task.add_done_callback(self._pending_topics.discard)

    @property
    def lease_holder(self) -> str | None:
        """The vehicle's lease holder as its last status said (None: free or not heard)."""
        return self._status.lease if self._status is not None else None

    def latest_jpeg(self) -> tuple[int, bytes | None]:
        count, jpeg = self.commander.camera(self.name)
        if jpeg is not None:
            return count, jpeg
        return super().latest_jpeg()

    # ------------------------------------------------------------------ calls
    @property
    def on_bus(self) -> bool:
        """Whether the vehicle is on the bus now (its liveliness token)."""
        return self.name in self._alive()

    @property
    def joined(self) -> bool:
        """Whether the vehicle can be commanded now: on the bus."""
        return self.on_bus

    async def _call_now(self, args: dict[str, Any], timeout_s: float) -> Any:
        rest = dict(args)
        op = str(rest.pop("op", ""))
        issued = rest.pop("issued", None)
        try:
            command = self.commander.new_command(
                self.name,
                op,
                rest,
                pilot=self._pilot(),
                issued=float(issued) if isinstance(issued, int | float) else None,
            )
        except (BusError, ValueError) as exc:
            raise ServiceError(f"{op}: {exc}") from exc
        try:
            reply = await self.commander.command(self.name, command, timeout_s)
        except NoReply as exc:
            if not self.on_bus:
                raise self._unavailable("is not on the bus") from exc
            raise RemoteCallError(str(exc)) from exc
        if reply.accepted:
            return reply.result
        log.warning("%s refused %s: %s", self.name, op, reply.reason)
        if reply.result:
            return {**reply.result, "accepted": False, "detail": reply.reason}
        if op in ("direct", "submit", "preempt", "cancel"):  # the dialog says the reason
            return {"accepted": False, "detail": reply.reason}
        raise ServiceError(f"{self.name}/{op} failed: {reply.reason}")

    async def call(
        self,
        args: dict[str, Any],
        timeout_s: float = CALL_TIMEOUT_S,
        *,
        join_wait_s: float | None = None,
        silent_s: float | None = None,
    ) -> Any:
        """A command on the bus, once the vehicle is on it (see
        :meth:`RemoteDroneStack.call`; the same waits and refusals).

        Raises:
            VehicleUnavailable: the vehicle is not on the bus (or silent).
            GraphError: the vehicle refused a read or fault, or did not answer in time.
        """
        await self.wait_joined(join_wait_s)
        if silent_s is not None and self.silent_for() > silent_s:
            raise self._unavailable(
                f"is not answering (silent for {self.silent_for():.1f} s); nothing was sent"
            )
        coro = self._call_now(args, timeout_s)
        if silent_s is None:
            return await coro
        return await self._unless_silent(coro, silent_s)

    def close(self) -> None:
        self._closed = True
        self._mirror_sub.undeclare()  # type: ignore[no-untyped-call]
        for sub in self._topic_subs:
            sub.close()
        for topic in self._advertised:
            self.graph.unadvertise(topic, self._owner)
        self.commander.unwatch(self.name)
        super().close()


def _fields(last: dict[str, Any]) -> dict[str, Any]:
    """The telemetry fields the 10 Hz bus telemetry keeps fresher than the 1 Hz status."""
    keep = ("x", "y", "z", "yaw_deg", "battery_pct", "ctrl_state", "link_ok", "flying")
    return {k: last[k] for k in keep if k in last}
