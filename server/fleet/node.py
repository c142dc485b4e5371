"""The fleet on the graph: ``CtmNode`` (central) and ``LtmNode`` (an in-process LTM).

Names (a drone's are prefixed ``/NAME``): status topic ``/NAME/fleet/ltm_status``
(``std_msgs/String``, ``data`` = ``LtmStatus`` JSON), flight-plan service
``/NAME/fleet/flight_plan`` (args = ``FlightPlan`` JSON object; answer ``{accepted, reason,
plan_id}``), and ``/fleet/status`` (``uav_console/FleetStatus``, latched) which doubles as the
CTM's heartbeat to every LTM. A vehicle process's LTM (``server.fleet.bus_ltm``) has the same
names on its own graph; its plans and its status travel on the bus (``server.fleet.failover``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Awaitable, Callable
from typing import Any

from server.fleet.ctm import CentralTaskManager
from server.fleet.errors import MessageError
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import (
    FLEET_TOPIC,
    FLEET_TYPE,
    PLAN_SERVICE,
    PLAN_SERVICE_TYPE,
    STATUS_TOPIC,
    STATUS_TYPE,
    LtmStatus,
)
from server.graph import Graph, GraphError
from server.msgs import header, stamp

log = logging.getLogger(__name__)
STATUS_SUFFIX = "/" + STATUS_TOPIC
# Live missions with coverage (``std_msgs/String``, ``data`` = ``{"missions": [mission_info…]}``,
# latched): time since each waypoint's last visit, longest wait, each handoff's revisit change.
MISSIONS_TOPIC = "/fleet/missions"
# What the operator must hear from the fleet (a mission stalled, resumed by itself): the
# console's replies, as the dialog speaks them (server.dialog.manager.REPLY)
REPLY_TOPIC = "/console/reply"
REPLY_TYPE = "uav_console/Reply"


def status_topic(name: str) -> str:
    return f"/{name}/{STATUS_TOPIC}"


def plan_service(name: str) -> str:
    return f"/{name}/{PLAN_SERVICE}"


class CtmNode:
    """Runs a ``CentralTaskManager`` on the graph (``await start()`` / ``await stop()``)."""

    def __init__(
        self,
        graph: Graph,
        ctm: CentralTaskManager,
        *,
        clock: Callable[[], float] = time.monotonic,
        period_s: float = 0.5,
        publish_period_s: float = 1.0,
        plan_timeout_s: float = 5.0,
    ) -> None:
        self.graph = graph
        self.ctm = ctm
        self.clock = clock
        self.period_s = period_s
        self.publish_period_s = publish_period_s
        self.plan_timeout_s = plan_timeout_s
        self.bad_messages = 0
        self._subs: dict[str, Any] = {}
        self._task: asyncio.Task[None] | None = None
        self._pending: set[asyncio.Task[None]] = set()
        self._next_publish = 0.0
        self._wake = asyncio.Event()
        graph.advertise(FLEET_TOPIC, FLEET_TYPE, latch=True)
        graph.advertise(MISSIONS_TOPIC, "std_msgs/String", latch=True)
        graph.advertise(REPLY_TOPIC, REPLY_TYPE)
        self._had_missions = False
        # Where the fleet has several consoles (server.fleet.failover): only the one holding
        # the central role decides, and it may send plans over the bus instead of the graph.
        self.active: Callable[[], bool] = lambda: True
        self.send_plan: Callable[[str, dict[str, Any], float], Awaitable[dict[str, Any]]] | None
        self.send_plan = None

    def poke(self) -> None:
        """Decide now (a mission was added)."""
        self._wake.set()

    def discover(self) -> None:
        """Subscribe to every LTM status topic on the graph not yet followed."""
        for topic, typ in self.graph.topics().items():
            if topic.endswith(STATUS_SUFFIX) and topic not in self._subs and typ == STATUS_TYPE:
                self._subs[topic] = self.graph.subscribe(topic, self._on_status)

    def _on_status(self, msg: dict[str, Any]) -> None:
        try:
            st = LtmStatus.from_dict(json.loads(msg.get("data", "")))
        except (MessageError, ValueError) as exc:
            self.bad_messages += 1
            log.warning("bad LTM status: %s", exc)
            return
        self.ctm.on_status(st, self.clock())

    async def tick(self) -> None:
        """One decision round: discover, decide, send plans, publish the fleet status."""
        now = self.clock()
        self.discover()
        for d in self.ctm.step(now) if self.active() else ():
            t = asyncio.create_task(self._send(d.drone, d.plan.to_dict(), d.plan.plan_id))
            self._pending.add(t)
            t.add_done_callback(self._pending.discard)
        self.tell()
        if now >= self._next_publish:
            self._next_publish = now + self.publish_period_s
            self.graph.publish(FLEET_TOPIC, self.ctm.fleet_status(now, stamp()))
            missions = self.ctm.missions_status(now)
            if missions or self._had_missions:
                self.graph.publish(MISSIONS_TOPIC, {"data": json.dumps({"missions": missions})})
            self._had_missions = bool(missions)

    def tell(self) -> None:
        """Say the CTM's notices on the console's replies (spoken, like the drones' alarms)."""
        while self.ctm.notices:
            _t, level, text = self.ctm.notices.popleft()
            msg = {
                "header": header(now=None),
                "text": text,
                "level": level,
                "speak": True,
                "utterance": "",
                "commands": "[]",
                "drone": "",
                "alarm": "fleet",
                "expects": "",
            }
            self.graph.publish(REPLY_TOPIC, msg)

    async def _send(self, name: str, plan: dict[str, Any], plan_id: int) -> None:
        try:
            if self.send_plan is not None:
                res = await self.send_plan(name, plan, self.plan_timeout_s)
            else:
                res = await self.graph.call_service(
                    plan_service(name), plan, timeout=self.plan_timeout_s
                )
            ok, reason = bool(res.get("accepted")), str(res.get("reason", ""))
        except GraphError as exc:
            ok, reason = False, f"not delivered: {exc}"
        self.ctm.on_plan_result(name, plan_id, ok, reason, self.clock())

    async def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="ctm")

    async def _run(self) -> None:
        while True:
            try:
                await self.tick()
            except Exception:  # a bug in one round must not stop the fleet
                log.exception("CTM round failed")
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), self.period_s)

    async def stop(self) -> None:
        for t in [self._task, *self._pending]:
            if t is not None:
                t.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await t


class LtmNode:
    """An in-process LTM on the graph: publishes its status, serves its flight-plan service."""

    def __init__(self, graph: Graph, ltm: LocalTaskManager, *, clock: Callable[[], float]) -> None:
        self.graph = graph
        self.ltm = ltm
        self.clock = clock
        self.topic = graph.advertise(status_topic(ltm.name), STATUS_TYPE)
        graph.advertise_service(plan_service(ltm.name), PLAN_SERVICE_TYPE, self._plan)
        self._sub = graph.subscribe(FLEET_TOPIC, self._heartbeat, type=FLEET_TYPE)

    async def _plan(self, args: dict[str, Any]) -> dict[str, Any]:
        return self.ltm.apply_plan_dict(args, self.clock())

    def _heartbeat(self, _msg: dict[str, Any]) -> None:
        self.ltm.heard_ctm(self.clock())

    def step(self, now: float) -> None:
        st = self.ltm.step(now)
        if st is not None:
            self.graph.publish(self.topic, {"data": json.dumps(st.to_dict())})

    def close(self) -> None:
        self._sub.close()
        self.graph.unadvertise(self.topic)
        self.graph.unadvertise_service(plan_service(self.ltm.name))
