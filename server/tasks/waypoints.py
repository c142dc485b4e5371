"""Fly map-frame or geodetic waypoints in order (the fleet's patrol routes)."""

from __future__ import annotations

import math
from dataclasses import replace

from drone.commands import Waypoint, Waypoints
from drone.control.pid import Setpoint
from drone.vehicle import VehicleSnapshot
from server.tasks.base import CRUISE_Z_M, Context, Outcome, PlanState, check_inside, need_flying
from server.tasks.errors import RefusedError
from server.tasks.legs import LegsTask


class WaypointsTask(LegsTask):
    """Fly map-frame (``x, y, z``) or geodetic (``lat, lon, alt``) waypoints in order.

    Command: ``{"action": "waypoints", "waypoints": [{"x":…, "y":…, "z":…} | {"lat":…, "lon":…,
    "alt":…}, …], "loop": false, "tolerance_m": 0.15, "yaw_deg": optional heading}``. Geodetic
    points need the world's ``gps_origin`` (local ENU by pymap3d). A waypoint may carry its own
    ``yaw_deg`` (the fleet's indoor patrol faces each marker). Used by the fleet manager.
    """

    name = "waypoints"

    def __init__(self, command: Waypoints) -> None:
        super().__init__(command)
        self.raw: list[Waypoint] = list(command.waypoints)
        self.loop = bool(command.loop)
        self.tolerance_m = float(command.tolerance_m) if command.tolerance_m else None
        self.yaw_deg = None if command.yaw_deg is None else float(command.yaw_deg)
        self.points: list[tuple[float, float, float]] | None = None

    def _resolve(self, ctx: Context) -> list[tuple[float, float, float]]:
        out = []
        origin = getattr(ctx.world, "gps_origin", None)
        for w in self.raw:
            if w.lat is not None and w.lon is not None:
                if origin is None:
                    raise RefusedError("This world has no GPS origin for lat/lon waypoints.")
                import pymap3d

                e, n, u = pymap3d.geodetic2enu(
                    float(w.lat),
                    float(w.lon),
                    float(origin.alt_m + CRUISE_Z_M if w.alt is None else w.alt),
                    origin.lat_deg,
                    origin.lon_deg,
                    origin.alt_m,
                )
                out.append((float(e), float(n), float(u)))
            else:
                assert w.x is not None and w.y is not None  # Waypoint's own rule
                z = CRUISE_Z_M if w.z is None else w.z
                out.append((float(w.x), float(w.y), float(z)))
        return out

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        need_flying(p, "fly the waypoints")
        self.points = self._resolve(ctx)
        for k, (x, y, z) in enumerate(self.points):
            check_inside(ctx, x, y, z, f"fly to waypoint {k + 1}")
        x, y, z = self.points[-1]
        self.needs_localisation = bool(getattr(ctx.world, "indoor", False) and ctx.world.markers)
        return replace(p, x=x, y=y, z=z, located=True)

    def start(self, ctx: Context, now: float) -> Outcome | None:
        if self.tolerance_m:
            self.arrival = replace(ctx.arrival, pos_tol_m=self.tolerance_m)
        return super().start(ctx, now)

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        pts = self.points or self._resolve(ctx)
        legs = []
        px, py = s.x, s.y
        for k, (x, y, z) in enumerate(pts):
            own = self.raw[k].yaw_deg if k < len(self.raw) else None
            yaw = (
                math.radians(own)  # this waypoint's own heading
                if own is not None
                else math.radians(self.yaw_deg)
                if self.yaw_deg is not None
                else math.atan2(y - py, x - px)
            )
            legs.append(Setpoint(x, y, z, yaw))
            px, py = x, y
        return legs, [f"waypoint {k + 1}/{len(pts)}" for k in range(len(pts))]

    def describe(self) -> str:
        return f"fly {len(self.raw)} waypoints"

    def done_text(self) -> str:
        return f"Reached all {len(self.raw)} waypoints"
