"""The Central patrol (CTANS): start, watch and stop a persistent multi-drone patrol from the
console, by its button or by voice, without writing a ``POST /missions`` body.

``CentralPatrol`` wraps the CTM with the world's own patrol route: the world's waypoints when it
has them (the outdoor field's square), else one stand-off pose per marker in id order (indoors:
1 m in front of each marker at its height, facing it, so the camera keeps localising the drone
all the way round). ``start`` adds the mission (every fleet drone is in the pool: one patrols,
the next relieves it at the handoff threshold), ``stop`` stops every running mission (the drones
fly home and land), ``status`` is what the console's Central panel shows: the mission with live
coverage (``server.fleet.continuity``) and each drone's role and battery.

REST (mounted with the fleet router under ``/api/v1``): ``GET /patrol``, ``POST /patrol``
(body optional: ``{"handoff_threshold": 0.3}``), ``DELETE /patrol``. Voice: the dialog's
``patrol_start`` / ``patrol_stop`` actions call :meth:`CentralPatrol.start` / ``stop``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from fastapi import APIRouter, HTTPException, params
from pydantic import BaseModel, Field

from server.fleet.ctm import CentralTaskManager
from server.fleet.errors import MissionError
from server.fleet.geo import Enu
from server.fleet.messages import Role

STANDOFF_M = 1.0  # indoors: as GotoMarkerTask.standoff_m, where the marker fills the camera
MISSION_PREFIX = "patrol"


@dataclass(frozen=True)
class PatrolReply:
    """What the operator is told; ``ok`` False means nothing changed."""

    ok: bool
    text: str
    mission: str = ""


def world_route(world: Any) -> tuple[list[Enu], list[float]]:
    """The world's patrol route and, indoors, the heading to hold at each waypoint.

    Raises:
        MissionError: the world has neither waypoints nor markers.
    """
    wps = getattr(world, "waypoints", ())
    if wps:
        return [Enu(*map(float, w.position)) for w in wps], []
    markers = sorted(getattr(world, "markers", ()), key=lambda m: m.id)
    if not markers:
        raise MissionError("this world has no waypoints and no markers to patrol")
    route, heads = [], []
    for m in markers:
        p = m.standoff(STANDOFF_M)
        route.append(Enu(float(p.x), float(p.y), float(p.z)))
        heads.append(math.degrees(p.yaw_rad))
    return route, heads


class CentralPatrol:
    """See the module docstring. ``on_change`` is called after a start or stop (the CTM node
    decides at once)."""

    def __init__(
        self,
        ctm: CentralTaskManager,
        world: Any,
        *,
        clock: Callable[[], float] = time.monotonic,
        on_change: Callable[[], None] | None = None,
    ) -> None:
        self.ctm = ctm
        self.world = world
        self.clock = clock
        self.on_change = on_change

    def running(self) -> list[str]:
        return [mid for mid, ms in self.ctm.missions.items() if ms.state != "stopped"]

    def start(self, threshold: float = 0.30) -> PatrolReply:
        """Start the world's patrol with every drone of the fleet (idempotent)."""
        now = self.clock()
        live = self.running()
        if live:
            ms = self.ctm.missions[live[0]]
            who = f"; {ms.active} is patrolling" if ms.active else ""
            return PatrolReply(False, f"The patrol is already running{who}.", live[0])
        try:
            route, heads = world_route(self.world)
            k = sum(1 for mid in self.ctm.missions if mid.startswith(MISSION_PREFIX)) + 1
            m = self.ctm.add_mission(
                route,
                now=now,
                loop=True,
                threshold=threshold,
                mission_id=f"{MISSION_PREFIX}{k}",
                headings_deg=heads,
            )
        except MissionError as exc:
            return PatrolReply(False, f"I cannot start the patrol: {exc}.")
        if self.on_change is not None:
            self.on_change()
        drones = [r for r in self.ctm.drones.values() if r.role is not Role.LOST]
        if not drones:
            text = (
                f"Patrol of {len(route)} waypoints set up, but no drone has joined the fleet "
                "yet; it starts when one does."
            )
        else:
            ready = [r for r in drones if r.role is Role.IDLE]
            text = (
                f"Starting the patrol of {len(route)} waypoints with {len(drones)} "
                f"drone{'s' if len(drones) != 1 else ''}; they hand over at "
                f"{100 * threshold:.0f} percent battery."
            )
            if not ready:
                text += " No drone is ready yet; the first one ready takes off."
        self.ctm.event(now, f"patrol {m.id} started from the console")
        return PatrolReply(True, text, m.id)

    def stop(self) -> PatrolReply:
        """Stop every running mission; its drones fly home and land."""
        now = self.clock()
        live = self.running()
        if not live:
            return PatrolReply(False, "No patrol is running.")
        for mid in live:
            self.ctm.stop_mission(mid, now)
        if self.on_change is not None:
            self.on_change()
        return PatrolReply(True, "Stopping the patrol; the drones are flying home.", live[0])

    def status(self) -> dict[str, Any]:
        """The Central panel's view: the running mission (with coverage) and every drone."""
        now = self.clock()
        live = self.running()
        mission = self.ctm.mission_info(live[0], now) if live else None
        drones = [
            {
                "name": r.name,
                "role": r.role.value,
                "battery": None if r.status is None else round(r.status.battery_pct, 1),
                "state": "UNKNOWN" if r.status is None else r.status.state,
                "mission": r.mission,
            }
            for r in sorted(self.ctm.drones.values(), key=lambda r: r.name)
        ]
        return {"running": bool(live), "mission": mission, "drones": drones}


class PatrolStart(BaseModel):
    """``POST /patrol``: optional knobs of the Central patrol."""

    handoff_threshold: float = Field(default=0.30, gt=0.0, lt=1.0)


def make_patrol_router(
    central: CentralPatrol, dependencies: Sequence[params.Depends] | None = None
) -> APIRouter:
    """``GET/POST/DELETE /patrol`` (mounted under ``/api/v1`` with the fleet router)."""
    router = APIRouter(tags=["fleet"], dependencies=list(dependencies or ()))

    @router.get("/patrol")
    async def patrol_status() -> dict[str, Any]:
        """The Central patrol: running mission with live coverage, every drone's role and
        battery."""
        return central.status()

    @router.post("/patrol")
    async def patrol_start(body: PatrolStart | None = None) -> dict[str, Any]:
        """Start the world's patrol with all drones (409 when one is already running)."""
        reply = central.start((body or PatrolStart()).handoff_threshold)
        if not reply.ok:
            code = 409 if reply.mission else 422
            raise HTTPException(status_code=code, detail=reply.text)
        return {"reply": reply.text, "mission": reply.mission, **central.status()}

    @router.delete("/patrol")
    async def patrol_stop() -> dict[str, Any]:
        """Stop the patrol; the drones fly home (404 when none is running)."""
        reply = central.stop()
        if not reply.ok:
            raise HTTPException(status_code=404, detail=reply.text)
        return {"reply": reply.text, "mission": reply.mission, **central.status()}

    return router
