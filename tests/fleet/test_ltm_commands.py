"""The LTM turns a flight plan into typed commands (drone/commands.py) whose JSON is the task
manager's ``waypoints`` command of DESIGN §4, and refuses a plan it cannot express rather than
raise."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from drone.commands import Command, wire
from server.fleet.geo import Enu
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import FlightPlan, PlanKind


@dataclass
class _Snapshot:
    flying: bool
    x: float = 1.0
    y: float = 2.0
    z: float = 0.0
    battery_pct: float = 90.0


@dataclass
class _Vehicle:
    """What the LTM asks of a vehicle here: its snapshot (no commander: nothing to set)."""

    snap: _Snapshot
    commander: Any = None

    def snapshot(self) -> _Snapshot:
        return self.snap


@dataclass
class _Decision:
    accepted: bool = True
    reason: str = ""
    task_id: int | None = None


@dataclass
class _Tasks:
    """A task manager that accepts everything and keeps what it was given."""

    submitted: list[list[Command]] = field(default_factory=list)

    def submit(self, commands: list[Command], *, replace: bool = False) -> list[_Decision]:
        self.submitted.append(list(commands))
        return [_Decision(task_id=i) for i, _ in enumerate(commands)]


SQUARE = (Enu(0, 0, 5), Enu(10, 0, 5), Enu(10, 10, 5))


def _ltm(snap: _Snapshot) -> tuple[LocalTaskManager, _Tasks]:
    tasks = _Tasks()
    return LocalTaskManager("uav1", _Vehicle(snap), tasks, Enu(0, 0, 0)), tasks


def test_a_patrol_plan_is_typed_commands_with_the_json_of_design() -> None:
    ltm, tasks = _ltm(_Snapshot(flying=False))
    plan = FlightPlan(
        3, PlanKind.PATROL, "m1", SQUARE, True, 1, 5.0, 1.5, (0.0, 90.0, 180.0), Enu(5, 0, 5)
    )
    assert ltm.apply_plan(plan, 0.0)[0]
    [sent] = tasks.submitted
    assert [wire(c) for c in sent] == [
        {"action": "takeoff"},
        {"action": "waypoints", "waypoints": [{"x": 5, "y": 0, "z": 5}], "tolerance_m": 1.5},
        {
            "action": "waypoints",
            "waypoints": [
                {"x": 10, "y": 0, "z": 5, "yaw_deg": 90.0},
                {"x": 10, "y": 10, "z": 5, "yaw_deg": 180.0},
                {"x": 0, "y": 0, "z": 5, "yaw_deg": 0.0},
            ],
            "loop": True,
            "tolerance_m": 1.5,
        },
    ]


def test_a_return_plan_flies_over_the_station_and_lands() -> None:
    ltm, tasks = _ltm(_Snapshot(flying=True))
    assert ltm.apply_plan(FlightPlan(4, PlanKind.RETURN, cruise_z=3.0), 0.0)[0]
    [sent] = tasks.submitted
    assert [wire(c) for c in sent] == [
        {
            "action": "waypoints",
            "waypoints": [{"x": 1.0, "y": 2.0, "z": 3.0}, {"x": 0, "y": 0, "z": 3.0}],
            "tolerance_m": 0.5,
        },
        {"action": "land"},
    ]


def test_a_plan_from_no_finite_position_is_refused_not_raised() -> None:
    ltm, tasks = _ltm(_Snapshot(flying=True, x=math.nan))
    ok, reason = ltm.apply_plan(FlightPlan(5, PlanKind.RETURN), 0.0)
    assert not ok and reason.startswith("refused: ") and "'x' must be a finite number" in reason
    assert tasks.submitted == []
