"""The Central patrol (CTANS): start, watch and stop a persistent multi-drone patrol from the
console, by its button or by voice, without writing a ``POST /missions`` body.

``CentralPatrol`` wraps the CTM with the world's own patrol route: the world's waypoints when it
has them (the outdoor field's square), else one stand-off pose per marker in id order (indoors:
1 m in front of each marker at its height, facing it, so the camera keeps localising the drone
all the way round). ``start`` adds the mission (every fleet drone is in the pool: one patrols,
the next relieves it at the handoff threshold), ``stop`` ends every live mission (the drones
fly home and land), ``pause`` and ``resume`` pause and resume it (server.fleet.states: Land,
Hover, Emergency or a jog on one of its drones pauses it too), ``status`` is what the console's
Central panel shows: the mission's state in words ("paused by the operator (land)") with its
drones' roles, live coverage (``server.fleet.continuity``) and each drone's role and battery.

REST (mounted with the fleet router under ``/api/v1``): ``GET /patrol``, ``POST /patrol``
(body optional: ``{"action": "start" | "pause" | "resume" | "end", "handoff_threshold": 0.3}``,
default start), ``DELETE /patrol`` (end). Voice: the dialog's ``patrol_start``,
``patrol_pause``, ``patrol_resume`` and ``patrol_stop`` actions call :meth:`CentralPatrol.start`,
``pause``, ``resume`` and ``stop``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, params
from pydantic import BaseModel, ConfigDict, Field

from server.fleet.ctm import CentralTaskManager
from server.fleet.errors import MissionError
from server.fleet.geo import Enu
from server.fleet.messages import DroneRole, Handoff
from server.fleet.states import MissionState

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
        """The missions not ended (waiting, running, paused or stalled): what ``stop`` ends."""
        return [mid for mid, ms in self.ctm.missions.items() if ms.state.live]

    def start(self, threshold: float = 0.30, handoff: Handoff = Handoff.PREDICTIVE) -> PatrolReply:
        """Start the world's patrol with every drone of the fleet (idempotent)."""
        now = self.clock()
        live = self.running()
        if live:
            ms = self.ctm.missions[live[0]]
            if ms.state is MissionState.PAUSED:
                return PatrolReply(
                    False,
                    f"The patrol is {ms.detail}; resume the patrol or end the patrol.",
                    live[0],
                )
            if ms.state is MissionState.STALLED:
                return PatrolReply(False, f"The patrol is {ms.detail}.", live[0])
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
                handoff=handoff,
            )
        except MissionError as exc:
            return PatrolReply(False, f"I cannot start the patrol: {exc}.")
        if self.on_change is not None:
            self.on_change()
        drones = [r for r in self.ctm.drones.values() if r.role is not DroneRole.LOST]
        reactive = handoff is Handoff.REACTIVE
        if not drones:
            text = (
                f"Patrol of {len(route)} waypoints set up, but no drone has joined the fleet "
                "yet; it starts when one does."
            )
        else:
            ready = [r for r in drones if r.role is DroneRole.IDLE]
            text = (
                f"Starting the patrol of {len(route)} waypoints with {len(drones)} "
                f"drone{'s' if len(drones) != 1 else ''}; they hand over at "
                f"{100 * threshold:.0f} percent battery"
                + (", leaving at the threshold as in the paper." if reactive else ".")
            )
            if not ready:
                text += " No drone is ready yet; the first one ready takes off."
        self.ctm.event(now, f"patrol {m.id} started from the console")
        return PatrolReply(True, text, m.id)

    def stop(self) -> PatrolReply:
        """End every live mission; its flying drones fly home and land."""
        now = self.clock()
        live = self.running()
        if not live:
            return PatrolReply(False, "No patrol is running.")
        flying = False  # a drone on its way or patrolling, or a paused one in the air
        for mid in live:
            ms = self.ctm.missions[mid]
            flying = flying or ms.active is not None or ms.relief is not None
            for name in ms.paused:
                st = self.ctm.drones[name].status if name in self.ctm.drones else None
                flying = flying or (st is not None and st.flying)
            self.ctm.end_mission(mid, now)
        self._changed()
        if not flying:
            return PatrolReply(True, "The patrol has ended; its drones are on the ground.", live[0])
        return PatrolReply(True, "Stopping the patrol; the drones are flying home.", live[0])

    def pause(self) -> PatrolReply:
        """Pause the live patrol: its flying drones hold where they are until resumed."""
        now = self.clock()
        live = [m for m in self.running() if self.ctm.missions[m].state is not MissionState.PAUSED]
        if not live:
            paused = bool(self.running())
            return PatrolReply(
                False, "The patrol is paused already." if paused else "No patrol is running."
            )
        for mid in live:
            self.ctm.pause_mission(mid, now, "pause")
        self._changed()
        return PatrolReply(True, "Pausing the patrol; the drones hold where they are.", live[0])

    def resume(self) -> PatrolReply:
        """Resume the paused patrol: the drone that reaches the route first flies it."""
        now = self.clock()
        paused = [m for m in self.running() if self.ctm.missions[m].state is MissionState.PAUSED]
        if not paused:
            if self.running():
                return PatrolReply(False, "The patrol is not paused.", self.running()[0])
            return PatrolReply(False, "No patrol is paused.")
        for mid in paused:
            self.ctm.resume_mission(mid, now)
        self._changed()
        return PatrolReply(
            True, "Resuming the patrol; the first drone ready flies to the route.", paused[0]
        )

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    def status(self) -> dict[str, Any]:
        """The Central panel's view: the live mission (its state in words, its drones' roles,
        coverage) and every drone. ``running``: a drone is on its way or patrolling."""
        now = self.clock()
        live = self.running()
        mission = self.ctm.mission_info(live[0], now) if live else None
        state = self.ctm.missions[live[0]].state if live else None
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
        return {
            "running": state is not None and state.flying,
            "state": state.value if state is not None else "none",
            "mission": mission,
            "drones": drones,
        }


class PatrolStatus(BaseModel):
    """``GET /patrol`` (:meth:`CentralPatrol.status`); ``POST``/``DELETE`` add ``reply``."""

    model_config = ConfigDict(extra="allow")

    running: bool = Field(description="a drone is on its way or patrolling")
    state: str = Field(description="the live mission's state, or 'none'")
    mission: dict[str, Any] | None = Field(description="the live mission (GET /missions/{id})")
    drones: list[dict[str, Any]] = Field(description="name, role, battery, state, mission")
    reply: str | None = Field(default=None, description="what was done, in words")


class PatrolStart(BaseModel):
    """``POST /patrol``: what to do (default: start) and the Central patrol's knobs."""

    action: Literal["start", "pause", "resume", "end"] = "start"
    handoff_threshold: float = Field(default=0.30, gt=0.0, lt=1.0)
    handoff: Handoff = Handoff.PREDICTIVE


def make_patrol_router(
    central: CentralPatrol, dependencies: Sequence[params.Depends] | None = None
) -> APIRouter:
    """``GET/POST/DELETE /patrol`` (mounted under ``/api/v1`` with the fleet router)."""
    router = APIRouter(tags=["fleet"], dependencies=list(dependencies or ()))

    @router.get("/patrol", response_model=PatrolStatus, response_model_exclude_unset=True)
    async def patrol_status() -> dict[str, Any]:
        """The Central patrol: running mission with live coverage, every drone's role and
        battery."""
        return central.status()

    @router.post("/patrol", response_model=PatrolStatus, response_model_exclude_unset=True)
    async def patrol_start(body: PatrolStart | None = None) -> dict[str, Any]:
        """Start the world's patrol with all drones (409 when one is live), or pause, resume
        or end it (``action``; 409 when the patrol is not in a state for it, 404 when there
        is none)."""
        body = body or PatrolStart()
        if body.action == "start":
            reply = central.start(body.handoff_threshold, body.handoff)
        elif body.action == "pause":
            reply = central.pause()
        elif body.action == "resume":
            reply = central.resume()
        else:
            reply = central.stop()
        if not reply.ok:
            if body.action == "start":
                code = 409 if reply.mission else 422
            else:
                code = 409 if central.running() else 404
            raise HTTPException(status_code=code, detail=reply.text)
        return {"reply": reply.text, "mission": reply.mission, **central.status()}

    @router.delete("/patrol", response_model=PatrolStatus, response_model_exclude_unset=True)
    async def patrol_stop() -> dict[str, Any]:
        """End the patrol; the drones fly home (404 when none is live)."""
        reply = central.stop()
        if not reply.ok:
            raise HTTPException(status_code=404, detail=reply.text)
        return {"reply": reply.text, "mission": reply.mission, **central.status()}

    return router
