"""Tasks made of setpoint legs flown in order, each with the arrival rule and a time limit.

Arrival (tum_ardrone's rule): within ``pos_tol_m`` (0.15 m, 3-D) and ``yaw_tol_deg`` (5°) of
the target, then staying inside for ``dwell_s`` (1 s); leaving resets the dwell. Each leg has a
time limit of ``20 s + 4 s/m``.
"""

from __future__ import annotations

import math

from drone.commands import Command
from drone.control.pid import Setpoint, wrap_angle
from drone.vehicle import VehicleSnapshot
from server.tasks.base import ArrivalRule, Context, Outcome, Task


class _Leg:
    """One setpoint with the arrival rule and a time limit."""

    def __init__(self, sp: Setpoint, rule: ArrivalRule, start_pose: VehicleSnapshot, now: float):
        self.sp = sp
        self.rule = rule
        dist = math.dist((start_pose.x, start_pose.y, start_pose.z), (sp.x, sp.y, sp.z))
        self.deadline = now + 20.0 + 4.0 * dist
        self.dist0 = max(dist, 1e-6)
        self.inside_since: float | None = None

    def error(self, s: VehicleSnapshot) -> tuple[float, float]:
        d = math.dist((s.x, s.y, s.z), (self.sp.x, self.sp.y, self.sp.z))
        dyaw = abs(math.degrees(wrap_angle(self.sp.yaw_rad - s.yaw_rad)))
        return d, dyaw

    def arrived(self, s: VehicleSnapshot, now: float) -> bool:
        d, dyaw = self.error(s)
        if d <= self.rule.pos_tol_m and dyaw <= self.rule.yaw_tol_deg:
            if self.inside_since is None:
                self.inside_since = now
            return now - self.inside_since >= self.rule.dwell_s
        self.inside_since = None
        return False

    def progress(self, s: VehicleSnapshot) -> float:
        d, _ = self.error(s)
        return max(0.0, min(1.0, 1.0 - d / self.dist0))

    def pause(self, dt: float) -> None:
        """Extend the time limit (time spent searching does not count)."""
        self.deadline += dt
        self.inside_since = None


class LegsTask(Task):
    """A task made of setpoint legs flown in order (goto, move, turn, patrol, waypoints…)."""

    loop = False
    arrival: ArrivalRule | None = None  # overrides the manager's rule (e.g. outdoor tolerance)

    def __init__(self, command: Command) -> None:
        super().__init__(command)
        self._legs: list[Setpoint] = []
        self._labels: list[str] = []
        self._own: list[int | None] = []  # each leg's index among the task's own (None: detour)
        self._i = 0
        self._leg: _Leg | None = None
        self.lap = 0

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        raise NotImplementedError

    def done_text(self) -> str:
        return f"{self.describe()}: done"

    def check_legs(self, ctx: Context, legs: list[Setpoint]) -> str | None:
        """Why the legs, computed when the task starts, cannot be flown (None: they can)."""
        return None

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        if not s.flying:
            return Outcome(False, "I'm not flying")
        if self.needs_position and not s.localised:
            self.detail = "finding my position first"
            return None  # the manager searches; the legs are computed once a marker is seen
        return self._first_leg(ctx, s, now)

    def _first_leg(self, ctx: Context, s: VehicleSnapshot, now: float) -> Outcome | None:
        self._legs, self._labels = self.legs(ctx, s)
        why = self.check_legs(ctx, self._legs)
        if why is not None:
            return Outcome(False, why)
        self._own = list(range(len(self._legs)))
        keep = getattr(ctx, "keep_away", None)  # round the people a leg passes too close to
        if keep is not None:
            way = keep.reroute((s.x, s.y), self._legs, loop=self.loop)
            if isinstance(way, str):
                return Outcome(False, way)
            labels = self._labels
            self._labels = [
                labels[i] if i is not None else f"going round {who}"
                for i, who in zip(way.origin, way.around, strict=True)
            ]
            self._legs, self._own = way.legs, way.origin
        self._begin_leg(ctx, s, now)
        return None

    def _begin_leg(self, ctx: Context, s: VehicleSnapshot, now: float) -> None:
        sp = self._legs[self._i]
        self._leg = _Leg(sp, self.arrival or ctx.arrival, s, now)
        self.target = sp
        ctx.vehicle.set_setpoint(sp)
        self.detail = self._labels[self._i]

    def pause(self, dt: float) -> None:
        if self._leg is not None:
            self._leg.pause(dt)

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        if not s.flying:
            return Outcome(False, "the drone is no longer flying")
        if self._leg is None:  # started before the drone knew its position (needs_position)
            if not s.localised:
                return None
            return self._first_leg(ctx, s, now)
        leg = self._leg
        n = len(self._legs)
        self.progress = (self._i + leg.progress(s)) / n
        if now > leg.deadline:
            d, dyaw = leg.error(s)
            off = f", {dyaw:.0f}° off its heading" if dyaw > leg.rule.yaw_tol_deg else ""
            return Outcome(False, f"timed out {d:.1f} m from {self._labels[self._i]}{off}")
        if not leg.arrived(s, now):
            return None
        own = self._own[self._i] if self._i < len(self._own) else self._i
        if own is not None:  # a detour round a person is no leg of the task's own
            self.on_leg_done(ctx, own)
        self._i += 1
        if self._i >= n:
            if not self.loop:
                self.progress = 1.0
                return Outcome(True, self.done_text())
            # the next lap starts at the task's own first leg: detours before it went round
            # people on the way from where the task started, which a lap does not fly
            self._i = self._own.index(0) if 0 in self._own else 0
            self.lap += 1
        self._begin_leg(ctx, s, now)
        return None

    def on_leg_done(self, ctx: Context, i: int) -> None:
        pass
