"""A recorded drone behind the REST door (:class:`ReplayDrone`) and the replay timeline's
command (:class:`ReplayCommand`): shared by ``uav-console replay`` (``replay_app``) and the
page's replays (``replay_live``)."""

from __future__ import annotations

import itertools
from typing import Any, Literal, cast

import numpy as np
from fastapi import HTTPException
from pydantic import BaseModel, ConfigDict, Field

from server.recorder.replay import Player
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
