"""Return home: fly to the nearest home station and land on it, or the autopilot's own return
to launch."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from drone.commands import Command, Land
from drone.control.pid import Setpoint
from drone.vehicle import VehicleSnapshot
from server.tasks.base import CRUISE_Z_M, Context, Outcome, PlanState, Task, need_flying
from server.tasks.errors import RefusedError
from server.tasks.flight import LandTask
from server.tasks.legs import LegsTask

RTL_TIMEOUT_S = 300.0  # an autopilot's own return to launch (MAVLink): 120 m at 1 m/s and back


class ReturnHomeTask(LegsTask):
    """Fly to the home station at cruise height, then land on it."""

    name = "return_home"
    needs_localisation = True

    def __init__(self, command: Command) -> None:
        super().__init__(command)
        self._landing: LandTask | None = None
        self._rtl = False

    def start(self, ctx: Context, now: float) -> Outcome | None:
        rtl = getattr(ctx.vehicle, "return_home", None)
        if rtl is None:
            return super().start(ctx, now)
        # An autopilot (MAVLink) flies its own return to launch: climb, fly home, land.
        Task.start(self, ctx, now)
        if not ctx.snapshot().flying:
            return Outcome(False, "I'm not flying")
        rtl()
        self._rtl = True
        self.detail = "returning to launch"
        return None

    def _home(self, ctx: Context, x: float, y: float) -> Any:
        stations = getattr(ctx.world, "stations", ())
        if not stations:
            raise RefusedError("This world has no home station to return to.")
        return min(stations, key=lambda st: math.hypot(st.position[0] - x, st.position[1] - y))

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        need_flying(p, "return home")
        h = self._home(ctx, p.x, p.y)
        return replace(p, flying=False, x=h.position[0], y=h.position[1], z=0.0, located=True)

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        h = self._home(ctx, s.x, s.y)
        sp = Setpoint(float(h.position[0]), float(h.position[1]), CRUISE_Z_M, s.yaw_rad)
        return [sp], [f"home station {h.id}"]

    def step(self, ctx: Context, now: float) -> Outcome | None:
        if self._rtl:
            s = ctx.snapshot()
            assert self.started_at is not None
            if not s.flying and s.ctrl_state in ("LANDED", "DEFAULT"):
                return Outcome(True, "Back home and landed")
            if now - self.started_at > RTL_TIMEOUT_S:
                return Outcome(False, f"return to launch did not finish in {RTL_TIMEOUT_S:.0f} s")
            return None
        if self._landing is not None:
            out = self._landing.step(ctx, now)
            if out is not None and out.ok:
                return Outcome(True, "Back home and landed")
            return out
        out = super().step(ctx, now)
        if out is not None and out.ok:
            self._landing = LandTask(Land())
            self.detail = "landing at home"
            return self._landing.start(ctx, now)
        return out

    def describe(self) -> str:
        return "return home"
