"""What every task is made of: the base ``Task``, the plan state, the outcome, the context a
task gets from the manager, and the checks shared by the kinds of task.

A task is planned before the drone moves (``plan``: raises ``RefusedError`` with a reason a
person can read; returns the predicted state after it, so "take off and go to marker 3" checks
the second command against a flying drone), then started and stepped by the ``TaskManager``.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drone.commands import Command, wire
from drone.control.pid import Setpoint
from drone.limits import FlightLimits
from drone.vehicle import Vehicle, VehicleSnapshot
from server.tasks.errors import RefusedError
from server.tasks.states import TaskState

_ids = itertools.count(1)

CRUISE_Z_M = 1.0  # height for return home and other legs without a stated height
MIN_Z_M = 0.3


@dataclass(frozen=True)
class ArrivalRule:
    """When a leg is reached: within ``pos_tol_m`` (3-D) and ``yaw_tol_deg`` of the target, then
    inside for ``dwell_s`` (tum_ardrone's rule, tightened)."""

    pos_tol_m: float = 0.15
    yaw_tol_deg: float = 5.0
    dwell_s: float = 1.0


@dataclass(frozen=True)
class PlanState:
    """What the drone is predicted to be doing when a queued command starts."""

    flying: bool
    x: float
    y: float
    z: float
    yaw_rad: float
    # Whether x, y are a known position (a marker fix, or a target the plan flies to); before
    # the first fix the estimate's (0, 0) is no position, so no fence can be judged from it.
    located: bool = True


@dataclass(frozen=True)
class Outcome:
    ok: bool
    text: str


class Context:
    """What tasks use from the manager (the manager implements it)."""

    vehicle: Vehicle
    world: Any
    arrival: ArrivalRule
    margin_m: float
    ceiling_m: float
    limits: FlightLimits
    describe_hook: Callable[[VehicleSnapshot], str] | None

    def snapshot(self) -> VehicleSnapshot:  # pragma: no cover - interface
        raise NotImplementedError

    def emit(self, kind: str, text: str) -> None:  # pragma: no cover - interface
        raise NotImplementedError


class Task:
    """Base class: subclasses set ``name`` and override ``plan``/``start``/``step``."""

    name = "task"
    # Needs a confident position from markers while it flies (the manager searches when lost).
    needs_localisation = False
    # Needs a known position (at least one marker fix) before its setpoints are computed: the
    # manager searches for a marker first when the drone has never had one (a move taken from
    # the unlocalised estimate would aim at a made-up place and jump with the first fix).
    needs_position = False

    def __init__(self, command: Command) -> None:
        self.id = next(_ids)
        self.command = wire(command)  # as said, for the dialog's replies and the status
        self.state = TaskState.QUEUED
        self.progress = 0.0
        self.detail = ""
        self.result = ""
        self.started_at: float | None = None
        self.target: Setpoint | None = None  # the setpoint to restore after a search

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        """Check the command against the predicted state; return the state after it.

        Raises:
            RefusedError: it cannot be done (the message says why).
        """
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        self.started_at = now
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        return None

    def describe(self) -> str:
        return self.name


def need_flying(p: PlanState, what: str) -> None:
    """Refuse ``what`` up front when the drone is predicted to be on the ground."""
    if not p.flying:
        raise RefusedError(f"I can't {what}: I'm not flying. Say 'take off' first.")


def check_inside(
    ctx: Context, x: float, y: float, z: float, what: str, located: bool = True
) -> None:
    """Refuse up front a target outside the world's limits (fence, floor, ceiling).

    ``located`` False: (x, y) come from no known position, so only the height is judged here;
    the task judges the fence when it starts, from where the drone then is.
    """
    why = ctx.limits.violation(x, y, z) if located else ctx.limits.height_violation(z)
    if why is not None:
        raise RefusedError(f"I can't {what}: {why}.")
