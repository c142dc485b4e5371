"""``CentralWatch``: what a vehicle does when its central server goes quiet (sans-I/O).

The central server sends ``/vehicles/heartbeat`` at 10 Hz. A vehicle that hears nothing from it
for ``hover_after_s`` (the web process stalled, crashed or restarts) stops whatever it was doing
and hovers where it is; if the silence lasts ``land_after_s`` it lands. One action per step and
each at most once per silence; hearing the server again ends the silence (the drone keeps
hovering until someone commands it: nothing resumes on its own).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class LossAction(enum.Enum):
    HOVER = "hover"
    LAND = "land"


@dataclass
class CentralWatch:
    hover_after_s: float = 1.0
    land_after_s: float = 20.0
    hovered: bool = False
    landed: bool = False
    losses: int = 0

    def __post_init__(self) -> None:
        if not 0 < self.hover_after_s < self.land_after_s:
            raise ValueError("need 0 < hover_after_s < land_after_s")

    def step(self, now: float, last_heard: float, flying: bool) -> LossAction | None:
        """The action due now, given the time the server was last heard from."""
        silent = now - last_heard
        if silent < self.hover_after_s:
            self.hovered = self.landed = False
            return None
        if not self.hovered:
            self.hovered = True
            self.losses += 1
            if flying:
                return LossAction.HOVER
        if silent >= self.land_after_s and not self.landed:
            self.landed = True
            if flying:
                return LossAction.LAND
        return None
