"""``uav-console replay FILE.mcap``: the console, read-only, on a recorded flight.

The app is the ordinary one (``server.app.create_app``) with no drone and no recorder; the
:class:`~server.recorder.replay.Player` publishes the recording onto its graph, so the
rosbridge door, the console page (camera, telemetry, map with trail, dialog) and rosapi see the
recorded topics as if live. The REST door gets one read-only drone per recorded drone
(``GET /api/v1/drones``, ``/drones/{id}``, ``video.mjpg`` and ``describe`` on the recorded
camera); commands answer 409. ``/api/v1/replay`` is the timeline: ``GET`` its state,
``POST {"action": "play"|"pause"|"seek"|"speed", "position_s", "speed"}`` to drive it.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any, cast

from fastapi import APIRouter, FastAPI, HTTPException, Request

from server.api.deps import RoleDep
from server.recorder.index import drones_of, iso
from server.recorder.mcapfile import Recording
from server.recorder.replay import Played, Player, Timeline, flight_start_ns
from server.recorder.replay_drone import ReplayCommand, ReplayDrone, ReplayStatus
from server.settings import Settings


def _player(request: Request) -> Player:
    player = getattr(request.app.state, "player", None)
    if player is None:
        raise HTTPException(status_code=404, detail="not a replay")
    return cast(Player, player)


def _status(request: Request) -> dict[str, Any]:
    player = _player(request)
    info = request.app.state.replay_info
    tl = player.timeline
    tl.update(player.now())
    return {**info, **tl.status(), "started": iso(tl.start_ns), "ended": iso(tl.end_ns)}


router = APIRouter(prefix="/replay", tags=["replay"])


@router.get("", response_model=ReplayStatus)
async def replay_status(request: Request, _role: RoleDep) -> dict[str, Any]:
    """The timeline: file, position, duration, playing, speed."""
    return _status(request)


@router.post("", response_model=ReplayStatus)
async def replay_control(body: ReplayCommand, request: Request, _role: RoleDep) -> dict[str, Any]:
    """Play, pause, seek (``position_s`` from the start) or set the ``speed``."""
    player = _player(request)
    if body.action == "play":
        player.play()
    elif body.action == "pause":
        player.pause()
    elif body.action == "seek":
        if body.position_s is None:
            raise HTTPException(status_code=422, detail="seek needs position_s")
        player.seek(body.position_s)
    else:
        if body.speed is None:
            raise HTTPException(status_code=422, detail="speed needs speed")
        player.set_speed(body.speed)
    return _status(request)


def create_replay_app(
    path: Path,
    recording: Recording,
    played: list[Played],
    *,
    speed: float = 1.0,
    settings: Settings | None = None,
) -> FastAPI:
    """The console app playing ``recording`` (see the module docstring)."""
    from server.app import create_app

    base = settings or Settings.from_env()
    world = recording.metadata.get("flight", {}).get("world") or base.world
    # a replay flies nothing and hears no one: no vehicle processes, no speech model at start
    settings = base.with_(
        drone="none", recorder=False, world=world, vehicles="inline", asr_preload=False
    )
    app = create_app(settings)
    runtime = app.state.runtime
    timeline = Timeline(played, speed, start_ns=flight_start_ns(recording))
    names = drones_of(list(recording.topics)) or ["uav1"]
    # A drone's topics are prefixed /NAME in a fleet and bare for a single drone (DESIGN §4).
    prefixes = {
        n: f"/{n}" if any(t.startswith(f"/{n}/ardrone/") for t in recording.topics) else ""
        for n in names
    }
    inner = app.router.lifespan_context

    @contextlib.asynccontextmanager
    async def lifespan(a: FastAPI) -> AsyncIterator[None]:
        async with inner(a):
            player = Player(runtime.graph, timeline)
            a.state.player = player
            player.advertise()
            for name in names:
                runtime.drones[name] = ReplayDrone.make(name, prefixes[name], player)
            task = asyncio.create_task(player.run(), name="replay")
            if not getattr(a.state, "start_paused", False):
                player.play()
            else:
                player.seek(0.0)
            try:
                yield
            finally:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
                runtime.drones.clear()

    app.router.lifespan_context = lifespan
    app.include_router(router, prefix="/api/v1")
    app.state.replay_info = {
        "file": str(path),
        "id": recording.metadata.get("flight", {}).get("id", path.stem),
        "drones": names,
        "complete": recording.complete,
    }
    return app
