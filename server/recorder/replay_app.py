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
import itertools
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
from fastapi import APIRouter, FastAPI, HTTPException, Request
from pydantic import BaseModel, ConfigDict, Field

from server.api.deps import RoleDep
from server.recorder.index import drones_of, iso
from server.recorder.mcapfile import Recording
from server.recorder.replay import Played, Player, Timeline, flight_start_ns
from server.settings import Settings
from server.vehicles.stack import DroneStack

IMAGE = "sensor_msgs/CompressedImage"
NAVDATA = "ardrone_autonomy/Navdata"
LINK_LOST_NS = 500_000_000  # no navdata for 0.5 s: the link is lost (DESIGN §5)


class _RecordedCamera:
    """Stands in for the driver where the runtime asks for the latest camera frame."""

    def __init__(self, stack: ReplayDrone) -> None:
        self._stack = stack

    @property
    def latest_frame(self) -> Any:
        import cv2

        _, jpeg = self._stack.latest_jpeg()
        if jpeg is None:
            return None
        return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)


class ReplayDrone(DroneStack):
    """One recorded drone behind the REST door: what it reported, nothing to command."""

    player: Player
    _frames: itertools.count[int]
    _last_image: int | None
    _jpeg: tuple[int, bytes | None]

    @classmethod
    def make(cls, name: str, prefix: str, player: Player) -> ReplayDrone:
        stack = cls(name, prefix, vehicle=cast(Any, None), driver=cast(Any, None))
        stack.player = player
        stack.driver = cast(Any, _RecordedCamera(stack))
        stack._frames = itertools.count()
        stack._last_image = None
        stack._jpeg = (-1, None)
        return stack

    def _latest(self, topic: str) -> dict[str, Any] | None:
        return self.player.latest.get(f"{self.prefix}{topic}")

    def link_ok(self) -> bool:
        return self._link() is True

    def _link(self) -> bool | None:
        """Whether the drone's navdata was flowing at this moment of the recording (DESIGN §5:
        lost after 0.5 s without); None before its first navdata."""
        t = self.player.latest_ns.get(f"{self.prefix}/ardrone/navdata")
        if t is None:
            return None
        tl = self.player.timeline
        tl.update(self.player.now())
        return tl.position_ns - t <= LINK_LOST_NS

    def telemetry(self) -> dict[str, Any]:
        nav = self._latest("/ardrone/navdata") or {}
        pose = (self._latest("/uav/pose") or {}).get("pose", {}).get("position", {})
        out: dict[str, Any] = {
            "name": self.name,
            "simulated": False,
            "replay": True,
            "link_ok": self._link(),
            "task": self._latest("/uav/task"),
        }
        if nav:
            out["battery_pct"] = nav.get("batteryPercent")
            out["altitude_m"] = (nav.get("altd") or 0) / 1000.0
            out["navdata"] = nav
        if pose:
            out.update({k: pose.get(k) for k in ("x", "y", "z")})
        return out

    def direct(self, action: str) -> str:
        raise HTTPException(status_code=409, detail=f"replay is read-only: cannot {action}")

    def latest_jpeg(self) -> tuple[int, bytes | None]:
        img = self._latest("/ardrone/image_raw/compressed")
        if img is None:
            return -1, None
        if id(img) != self._last_image:
            self._last_image = id(img)
            data = img.get("data")
            self._jpeg = (next(self._frames), bytes(data) if data is not None else None)
        return self._jpeg

    def truth(self) -> dict[str, Any]:
        raise HTTPException(status_code=404, detail="a replay has no simulator ground truth")


class ReplayCommand(BaseModel):
    action: Literal["play", "pause", "seek", "speed"]
    position_s: float | None = Field(default=None, ge=0)
    speed: float | None = Field(default=None, gt=0, le=100)


class ReplayStatus(BaseModel):
    """``GET``/``POST /replay``: the recording and where the timeline stands."""

    model_config = ConfigDict(extra="allow")

    file: str
    id: str
    drones: list[str]
    complete: bool
    playing: bool
    speed: float
    position_s: float
    duration_s: float
    start_ns: int
    end_ns: int
    messages: int
    started: str | None
    ended: str | None


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
    settings = base.with_(drone="none", recorder=False, world=world)
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
