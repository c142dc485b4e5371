"""Patrol markers (or a GPS world's waypoints) in a loop, one goto leg each."""

from __future__ import annotations

from drone.commands import Goto, Patrol
from drone.control.pid import Setpoint
from drone.vehicle import VehicleSnapshot
from server.tasks.base import Context, PlanState
from server.tasks.errors import CommandError
from server.tasks.goto import GotoMarkerTask
from server.tasks.legs import LegsTask


class PatrolTask(LegsTask):
    name = "patrol"
    needs_localisation = True
    needs_position = True
    loop = True

    def __init__(self, command: Patrol) -> None:
        super().__init__(command)
        by_waypoint = command.markers is None and command.waypoints is not None
        ids = command.waypoints if by_waypoint else command.markers
        if not ids:
            raise CommandError("'patrol' needs 'markers', a non-empty list of marker ids")
        self.markers = list(ids)
        self._gotos = [
            GotoMarkerTask(Goto(waypoint=m) if by_waypoint else Goto(marker=m))
            for m in self.markers
        ]

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        for g in self._gotos:
            p = g.plan(p, ctx)
        self.needs_localisation = any(g.needs_localisation for g in self._gotos)
        return p

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        legs = [g.standoff_setpoint(ctx) for g in self._gotos]
        self.needs_localisation = any(g.needs_localisation for g in self._gotos)
        return legs, [f"{g.kind} {g.marker}" for g in self._gotos]

    def on_leg_done(self, ctx: Context, i: int) -> None:
        ctx.emit("progress", f"Reached {self._gotos[i].kind} {self.markers[i]}")

    def describe(self) -> str:
        return f"patrol {self._gotos[0].kind}s " + ", ".join(str(m) for m in self.markers)
