"""The vehicle's LTM on the bus (server.fleet.bus_ltm): which drone the LTM's grace keeps (and
the console watch leaves alone), and plans that are not plans refused with the reason."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import pytest

from server.fleet.bus_ltm import MAX_PLAN_BYTES, BusLtmNode
from server.fleet.geo import Enu
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import FlightPlan, PlanKind
from server.graph import Graph


@dataclass
class Snapshot:
    flying: bool = True
    x: float = 0.0
    y: float = 0.0
    z: float = 1.0


@dataclass
class FakeVehicle:
    """What the LTM reads of a vehicle here: its snapshot."""

    snap: Snapshot = field(default_factory=Snapshot)
    commander: Any = None

    def snapshot(self) -> Snapshot:
        return self.snap


@dataclass
class FakeTasks:
    """The task manager's cancel, as the LTM calls it for a ``none`` plan."""

    cancelled: list[str] = field(default_factory=list)

    def cancel(self, reason: str) -> None:
        self.cancelled.append(reason)


async def node() -> tuple[BusLtmNode, FakeVehicle]:
    import asyncio

    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    vehicle = FakeVehicle()
    ltm = LocalTaskManager("uav1", vehicle, FakeTasks(), Enu(1.0, 3.0, 0.0))
    return BusLtmNode(graph, ltm, clock=lambda: 0.0), vehicle


PATROL = FlightPlan(5, PlanKind.PATROL, route=(Enu(0, 0, 1),))


@pytest.mark.parametrize(
    ("plan", "flying", "operator", "held", "kept"),
    [
        (None, True, "", "", False),  # direct control: the console watch keeps it
        (PATROL, True, "", "", True),
        (PATROL, False, "", "", False),  # on the ground: nothing to keep flying
        (FlightPlan(6, PlanKind.RETURN), True, "", "", True),  # on its way home
        (FlightPlan(7, PlanKind.HOLD), True, "", "", False),  # a paused mission's hover
        (PATROL, True, "land", "", False),  # the operator took it: direct control
        (PATROL, True, "", "navdata monitor (hover)", False),  # held for the operator
    ],
)
async def test_which_drone_the_grace_keeps(
    plan: FlightPlan | None, flying: bool, operator: str, held: str, kept: bool
) -> None:
    n, vehicle = await node()
    n.ltm.plan, n.ltm.operator, n.ltm.held = plan, operator, held
    vehicle.snap.flying = flying
    assert n.flying_a_plan() is kept
    n.close()


async def test_plans_on_the_bus_are_judged_and_bad_ones_refused_with_the_reason() -> None:
    n, _ = await node()
    ok = json.loads(await n._bus_plan(json.dumps({"plan_id": 3, "kind": "none"}).encode()))
    assert ok == {"accepted": True, "reason": "cancelled", "plan_id": 3}
    for payload, why in [
        (b"\xff not json", "refused: "),
        (b'{"plan_id": 4, "kind": "teleport"}', "refused: field 'kind' must be one of"),
        (b"[1, 2]", "refused: flight plan must be a JSON object"),
        (b"{" + b" " * MAX_PLAN_BYTES + b"}", f"refused: a plan of {MAX_PLAN_BYTES + 2} bytes"),
    ]:
        out = json.loads(await n._bus_plan(payload))
        assert out["accepted"] is False and out["reason"].startswith(why), out
    assert n.ltm.plan is not None and n.ltm.plan.plan_id == 3  # nothing bad was applied
    n.close()
