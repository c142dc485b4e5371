"""ANS monitors: the estimator against the drone's own sensors, the clamped jog,
and the ceiling the altitude monitor watches (the world's, not a global number).

They follow :mod:`server.dialog.autonomic`'s contract (``name``, ``period_s``,
``check(snap, state, now) -> Alarm | None``) and latch the same way: told once per episode.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from server.dialog.autonomic import Alarm
from server.dialog.ports import VehicleSnapshot
from server.dialog.states import State

FALLBACK_CEILING_M = 2.8
"""Only when nothing states the world's ceiling (a fake vehicle port): the AR.Drone's default
``control:altitude_max`` of 3 m, less 0.2 m."""


def ans_ceiling_m(setting: float | None, vehicle_port: Any) -> float:
    """The ceiling the ANS watches: the world's (``vehicle_port.ceiling_m``), lowered by the
    ``altitude_ceiling_m`` setting when one is given (a setting never raises it)."""
    world = getattr(vehicle_port, "ceiling_m", None)
    candidates = [float(v) for v in (setting, world) if isinstance(v, int | float)]
    return min(candidates) if candidates else FALLBACK_CEILING_M


@dataclass
class EstimatorMonitor:
    """The pose estimate disagrees with navdata (components gated out again and again), or the
    EKF had to restart a part of its state from navdata: tell the operator."""

    period_s: float = 0.25
    # Not "estimator": that is server.dialog.monitors' (no position fix); the ANS runs each
    # monitor on the period kept under its name, so two of one name silence one of them.
    name: str = "estimator_sensors"
    _told: bool = False
    _reinits: int = 0

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        parts = ", ".join(snap.estimator_disagreement)
        if snap.estimator_reinits > self._reinits:
            self._reinits = snap.estimator_reinits
            self._told = bool(parts)
            return Alarm(
                self.name,
                "alert",
                "My position estimate disagreed with the drone's own sensors; I reset it from "
                "them. Watch the drone.",
            )
        if parts and not self._told:
            self._told = True
            return Alarm(
                self.name,
                "alert",
                f"My position estimate disagrees with the drone's sensors ({parts}).",
            )
        if not parts:
            self._told = False
        return None


@dataclass
class JogLimitMonitor:
    """The manual jog was slowed or stopped near a wall, the floor or the ceiling: say why."""

    period_s: float = 0.25
    name: str = "jog_limit"
    _said: str = ""

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        why = snap.jog_limit
        if not why:
            self._said = ""
            return None
        kind = why.split(" ", 1)[0]  # "stopped" / "slowed": tell again when it changes
        if kind == self._said:
            return None
        self._said = kind
        return Alarm(self.name, "warn", f"Jog limited: {why}.")
