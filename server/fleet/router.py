"""REST doors onto the CTM: ``POST /missions``, ``GET /missions``, ``GET /missions/{id}``,
``POST /missions/{id}`` (``{"action": "pause" | "resume" | "end"}``), ``DELETE /missions/{id}``
(end), ``GET /fleet`` (mounted by the app under ``/api/v1``)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, params
from pydantic import BaseModel, ConfigDict, Field

from server.fleet.ctm import CentralTaskManager
from server.fleet.errors import IllegalTransition, MissionError, NotFoundError
from server.fleet.messages import MissionRequest


class MissionControl(BaseModel):
    """``POST /missions/{id}``: the operator pauses, resumes or ends a mission."""

    action: Literal["pause", "resume", "end"]


Num = int | float
"""A JSON number as the CTM wrote it (an integer stays an integer on the wire)."""


class MissionInfo(BaseModel):
    """A mission as ``GET /missions/{id}`` answers it (``CentralTaskManager.mission_info``)."""

    model_config = ConfigDict(extra="allow")

    id: str
    state: str
    detail: str = Field(description="the state in words")
    drones: list[dict[str, str]] = Field(description="name and role (paused: was, operator)")
    loop: bool
    handoff_threshold: Num
    handoff: str = Field(description="reactive or predictive")
    route: list[dict[str, Num]] = Field(description="map-frame points x, y, z (m)")
    route_geo: list[dict[str, Num]] = Field(description="the same as lat, lon, alt")
    active: str | None
    relief: str | None
    handoffs: int
    replacements: int
    coverage: dict[str, Any] | None = Field(description="time since each point's last visit")


class FleetStatus(BaseModel):
    """``GET /fleet``: the ``uav_console/FleetStatus`` message of ``/fleet/status``."""

    model_config = ConfigDict(extra="allow")

    header: dict[str, Any]
    drones: list[dict[str, Any]] = Field(description="name, role, position, battery, state…")
    events: list[str]


class CentralRoleInfo(BaseModel):
    """``GET /central``: who holds the fleet's central role, as this console sees it; on a
    bus also the console and fleet names, the consoles and holders seen, takeover times."""

    model_config = ConfigDict(extra="allow")

    role: str = Field(description="central, standby, or only (a console on no bus)")
    central: str | None = Field(description="the console holding the role (null: none seen)")
    console: str | None = None
    fleet: str | None = None
    consoles: list[str] | None = None
    holders: list[str] | None = None
    takeovers_s: list[float] | None = None
    claimed_unix: float | None = None
    lost_holder_unix: float | None = None
    replicas_in: int | None = None
    on_bus: list[str] | None = None


def make_fleet_router(
    ctm: CentralTaskManager,
    *,
    clock: Callable[[], float] = time.monotonic,
    dependencies: Sequence[params.Depends] | None = None,
    on_change: Callable[[], None] | None = None,
) -> APIRouter:
    """The fleet router. ``clock`` must be the clock the CTM is stepped with; ``on_change``
    is called after a mission is added or stopped (the node steps the CTM at once)."""
    router = APIRouter(tags=["fleet"], dependencies=list(dependencies or ()))

    def changed() -> None:
        if on_change is not None:
            on_change()

    @router.post("/missions", status_code=201, response_model=MissionInfo)
    async def create_mission(req: MissionRequest) -> dict[str, Any]:
        """Start a patrol: route as lat/lon/alt waypoints or marker ids, loop, threshold."""
        try:
            m = ctm.mission_from_request(req, clock())
        except MissionError as exc:
            raise HTTPException(status_code=422, detail=str(exc)) from exc
        changed()
        return ctm.mission_info(m.id, clock())

    @router.get("/missions", response_model=list[MissionInfo])
    async def list_missions() -> list[dict[str, Any]]:
        return [ctm.mission_info(mid, clock()) for mid in ctm.missions]

    @router.get("/missions/{mission_id}", response_model=MissionInfo)
    async def get_mission(mission_id: str) -> dict[str, Any]:
        try:
            return ctm.mission_info(mission_id, clock())
        except NotFoundError as exc:
            raise HTTPException(status_code=404, detail=str(exc)) from exc

    @router.post("/missions/{mission_id}", response_model=MissionInfo)
    async def control_mission(mission_id: str, body: MissionControl) -> dict[str, Any]:
        """Pause, resume or end a mission (409 when its state does not allow it: resuming a
        mission that is not paused, pausing an ended one)."""
        try:
            ctm.control_mission(mission_id, body.action, clock())
        except NotFoundError as exc:
            raise HTTPException(status_code=404, detail=str(exc)) from exc
        except IllegalTransition as exc:
            raise HTTPException(status_code=409, detail=str(exc)) from exc
        changed()
        return ctm.mission_info(mission_id, clock())

    @router.delete("/missions/{mission_id}", response_model=MissionInfo)
    async def end_mission(mission_id: str) -> dict[str, Any]:
        """End a mission; its drones fly home."""
        try:
            ctm.end_mission(mission_id, clock())
        except NotFoundError as exc:
            raise HTTPException(status_code=404, detail=str(exc)) from exc
        changed()
        return ctm.mission_info(mission_id, clock())

    @router.get("/fleet", response_model=FleetStatus)
    async def fleet() -> dict[str, Any]:
        """The same content as the ``/fleet/status`` topic."""
        return ctm.fleet_status(clock())

    return router
