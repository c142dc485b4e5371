"""The flight-state tasks: take off, land, cut the motors, hover."""

from __future__ import annotations

from dataclasses import replace

from drone.control.pid import Setpoint
from server.tasks.base import Context, Outcome, PlanState, Task, need_flying


class TakeoffTask(Task):
    name = "takeoff"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        return replace(p, flying=True, z=max(p.z, 0.8))

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        if s.flying:
            return Outcome(True, "Already flying")
        if s.emergency:
            return Outcome(False, "the drone is in emergency; reset it first")
        ctx.vehicle.takeoff()
        self.detail = "taking off"
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        assert self.started_at is not None
        self.progress = min(1.0, s.altitude_m / 0.8)
        if s.flying and s.ctrl_state in ("HOVERING", "FLYING"):
            return Outcome(True, "Took off")
        if now - self.started_at > 10.0:
            return Outcome(False, f"take-off did not finish within 10 s (state {s.ctrl_state})")
        return None


class LandTask(Task):
    name = "land"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        return replace(p, flying=False, z=0.0)

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        ctx.vehicle.land()
        self.detail = "landing"
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        assert self.started_at is not None
        if not s.flying and s.ctrl_state in ("LANDED", "DEFAULT"):
            return Outcome(True, "Landed")
        if now - self.started_at > 15.0:
            return Outcome(False, f"landing did not finish within 15 s (state {s.ctrl_state})")
        return None


class EmergencyTask(Task):
    name = "emergency"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        return replace(p, flying=False, z=0.0)

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        ctx.vehicle.emergency()
        return Outcome(True, "Motors cut (emergency)")


class HoverTask(Task):
    name = "hover"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        need_flying(p, "hover")
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        # A vehicle whose autopilot holds position (MAVLink) hovers in its own hold mode; the
        # others hold the estimate with the position controller when they know where they are.
        if s.localised and not ctx.vehicle.holds_position:
            ctx.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad))
        else:
            ctx.vehicle.hover()
        return Outcome(True, "Hovering")
