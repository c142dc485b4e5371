"""Go to a marker's stand-off pose, or to a GPS world's numbered waypoint."""

from __future__ import annotations

from dataclasses import replace

from drone.commands import Goto
from drone.control.pid import Setpoint
from drone.vehicle import VehicleSnapshot
from server.tasks.base import Context, PlanState, check_inside, need_flying
from server.tasks.errors import CommandError, RefusedError
from server.tasks.legs import LegsTask


class GotoMarkerTask(LegsTask):
    """Fly to a marker's stand-off pose, or to a GPS world's numbered waypoint.

    A marker is flown to on marker localisation (the manager searches when the markers are
    lost); a waypoint of a GPS world is flown on the estimate the GPS keeps (no marker search),
    once the drone knows where it is.
    """

    name = "goto"
    needs_localisation = True
    needs_position = True
    standoff_m = 1.0

    def __init__(self, command: Goto) -> None:
        super().__init__(command)
        # "waypoint": the world's numbered waypoint (GPS worlds); a marker elsewhere.
        self.waypoint: int | None = None
        if command.marker is None and command.waypoint is not None:
            self.waypoint = command.waypoint
        elif command.marker is None:
            raise CommandError("'goto' needs 'marker' or 'waypoint'")
        self.marker = command.marker if command.marker is not None else command.waypoint
        self.kind = "marker" if self.waypoint is None else "waypoint"

    def standoff_setpoint(self, ctx: Context) -> Setpoint:
        if self.waypoint is not None and _has_waypoints(ctx):
            self.kind = "waypoint"
            self.needs_localisation = False  # the GPS keeps the position, not the markers
            x, y, z = _world_waypoint(ctx, self.waypoint)
            return Setpoint(x, y, z, ctx.snapshot().yaw_rad)
        self.kind = "marker"
        self.needs_localisation = True
        try:
            m = ctx.world.marker(self.marker)
        except KeyError:
            known = ", ".join(str(i) for i in ctx.world.marker_ids())
            raise RefusedError(
                f"There is no marker {self.marker}. Known markers: {known}."
            ) from None
        p = m.standoff(self.standoff_m)
        return Setpoint(float(p.x), float(p.y), float(p.z), float(p.yaw_rad))

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        sp = self.standoff_setpoint(ctx)
        need_flying(p, f"go to {self.kind} {self.marker}")
        check_inside(ctx, sp.x, sp.y, sp.z, f"go to {self.kind} {self.marker}")
        return replace(p, x=sp.x, y=sp.y, z=sp.z, yaw_rad=sp.yaw_rad, located=True)

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        return [self.standoff_setpoint(ctx)], [f"{self.kind} {self.marker}"]

    def describe(self) -> str:
        return f"go to {self.kind} {self.marker}"

    def done_text(self) -> str:
        return f"Reached {self.kind} {self.marker}"


def _has_waypoints(ctx: Context | None) -> bool:
    return ctx is not None and bool(getattr(ctx.world, "waypoints", ()))


def _world_waypoint(ctx: Context, n: int) -> tuple[float, float, float]:
    """Waypoint ``n`` of a GPS world (``wpN``, or the n-th in the file), map frame.

    Raises:
        RefusedError: no such waypoint (the reply lists the known ones).
    """
    wps = ctx.world.waypoints
    for w in wps:
        if w.id in (f"wp{n}", str(n)):
            return float(w.position[0]), float(w.position[1]), float(w.position[2])
    known = ", ".join(w.id.removeprefix("wp") for w in wps)
    raise RefusedError(f"There is no waypoint {n}. Known waypoints: {known}.")
