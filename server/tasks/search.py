"""Search: turn in place until a marker is seen."""

from __future__ import annotations

import math

from drone.control.pid import Setpoint
from server.tasks.base import Context, Outcome, PlanState, Task, need_flying

SEARCH_RATE_RAD_S = 0.5  # ~29°/s: a full turn in 12.6 s, slow enough for the detector
SEARCH_MAX_TURNS = 2.0


class SearchTask(Task):
    """Turn in place (holding height) until a marker is seen (tag search, on request, or by
    the task manager while idle when the pose is uncertain); reports what it found and where
    that puts the drone."""

    name = "search"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        need_flying(p, "search for markers")
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        self._t0_marker = s.last_marker_t
        ctx.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad, SEARCH_RATE_RAD_S))
        self.detail = "turning to find a marker"
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        assert self.started_at is not None
        if s.markers and s.last_marker_t is not None and s.last_marker_t != self._t0_marker:
            ctx.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad))
            ids = sorted({int(m.id) for m in s.markers})
            which = (
                f"marker {ids[0]}"
                if len(ids) == 1
                else "markers " + ", ".join(map(str, ids[:-1])) + f" and {ids[-1]}"
            )
            return Outcome(True, f"Found {which}; I am at x {s.x:.1f}, y {s.y:.1f} meters")
        limit = SEARCH_MAX_TURNS * 2 * math.pi / SEARCH_RATE_RAD_S
        self.progress = min(1.0, (now - self.started_at) / limit)
        if now - self.started_at > limit:
            return Outcome(False, "no marker in sight after turning around twice")
        return None
