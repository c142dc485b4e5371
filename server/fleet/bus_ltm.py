"""A vehicle's LTM on the bus as well as on its graph: plans from whichever console is central,
its status to every console, and the grace of a drone on a plan while no console is central.

:class:`BusLtmNode` is an :class:`~server.fleet.node.LtmNode` (the graph's plan service and
status topic stay) that also answers plans on ``uavc/<fleet>/<drone>/plan`` and publishes its
status on ``uavc/<fleet>/<drone>/ltm`` (:mod:`drone.bus.plans`). While a console holds the
central role (its token ``uavc/<fleet>/central/alive`` is on the bus) the LTM counts the central
as heard; when none does, a drone on a plan flies it on for the LTM's ``ctm_timeout_s`` (the
``central_grace_s`` setting, 60 s by default), then flies home, and at its battery reserve it
flies home anyway (``LocalTaskManager.step``).

:meth:`BusLtmNode.flying_a_plan` tells the vehicle's watch of its console
(``server.vehicles.watch.CentralWatch``: hover after 1 s of silence, land after 20 s) to leave
such a drone to the LTM; a drone under direct control (no plan, or taken by the operator, or held
by its safety monitor for the operator) keeps that watch.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Callable
from typing import Any

from drone.bus.plans import VehiclePlans, refusal
from server.fleet.errors import MessageError
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import PlanKind
from server.fleet.node import LtmNode
from server.graph import Graph

log = logging.getLogger("uav_console.vehicle")

MAX_PLAN_BYTES = 64 * 1024


class BusLtmNode(LtmNode):
    """See the module docstring; on the graph only (as :class:`LtmNode`) until
    :meth:`join_bus`."""

    def __init__(self, graph: Graph, ltm: LocalTaskManager, *, clock: Callable[[], float]) -> None:
        super().__init__(graph, ltm, clock=clock)
        self.plans: VehiclePlans | None = None

    def join_bus(self, session: Any, fleet: str) -> None:
        """Answer plans and publish the status on the bus too (``session``: the vehicle's)."""
        self.plans = VehiclePlans(
            session, fleet, self.ltm.name, asyncio.get_running_loop(), self._bus_plan
        )
        self.plans.start()

    async def _bus_plan(self, payload: bytes) -> bytes:
        """A plan query's payload → the reply (refused with the reason when it is not a plan)."""
        if len(payload) > MAX_PLAN_BYTES:
            return refusal(f"refused: a plan of {len(payload)} bytes (at most {MAX_PLAN_BYTES})")
        try:
            answer = self.ltm.apply_plan_dict(json.loads(payload), self.clock())
        except (ValueError, MessageError) as exc:  # MessageError, JSON errors: ValueErrors
            log.warning("%s: a plan on the bus refused: %s", self.ltm.name, exc)
            return refusal(f"refused: {exc}")
        return json.dumps(answer).encode()

    def step(self, now: float) -> None:
        if self.plans is not None and self.plans.central_alive:
            self.ltm.heard_ctm(now)
        st = self.ltm.step(now)
        if st is None:
            return
        data = json.dumps(st.to_dict())
        self.graph.publish(self.topic, {"data": data})
        if self.plans is not None:
            self.plans.publish_status(data.encode())

    def flying_a_plan(self) -> bool:
        """The drone flies the fleet's plan (a patrol, or home), not taken by the operator nor
        held by its safety monitor for them: the LTM, not the console watch, keeps it safe."""
        plan = self.ltm.plan
        return (
            plan is not None
            and bool(self.ltm.vehicle.snapshot().flying)
            and plan.kind in (PlanKind.PATROL, PlanKind.RETURN)
            and not self.ltm.operator
            and not self.ltm.held
        )

    def close(self) -> None:
        if self.plans is not None:
            self.plans.close()
            self.plans = None
        super().close()
