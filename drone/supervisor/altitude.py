"""Altitude: above the world's ceiling, warn and descend back under it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.phase import Phase
from drone.vehicle import VehicleSnapshot

FALLBACK_CEILING_M = 2.8
"""Only when nothing states the world's ceiling (no world): the AR.Drone's default
``control:altitude_max`` of 3 m, less 0.2 m."""

# MAVLink flight modes in which the autopilot itself climbs, returns or lands.
AUTOPILOT_RETURN_MODES = ("AUTO.RTL", "AUTO.LAND", "RTL", "LAND", "SMART_RTL")


def ceiling_of(setting: float | None, world: Any) -> float:
    """The ceiling the supervisor watches: the world's (drone/limits.py), lowered by the
    ``altitude_ceiling_m`` setting when one is given (a setting never raises it)."""
    candidates = [float(setting)] if isinstance(setting, int | float) else []
    if world is not None and hasattr(world, "bounds"):
        from drone.limits import limits_of

        candidates.append(float(limits_of(world).ceiling_m))
    return min(candidates) if candidates else FALLBACK_CEILING_M


@dataclass
class AltitudeMonitor:
    """Above the ceiling: warn and descend back under it."""

    ceiling_m: float
    period_s: float = 0.5
    margin_m: float = 0.2
    name: str = "altitude"
    _over: bool = False

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        if not snap.flying or snap.altitude_m <= self.ceiling_m:
            if snap.altitude_m < self.ceiling_m - self.margin_m:
                self._over = False
            return None
        if self._over:
            return None
        self._over = True
        down = round(snap.altitude_m - self.ceiling_m + self.margin_m, 2)
        mode = str(snap.extra.get("flight_mode") or "")
        if mode in AUTOPILOT_RETURN_MODES:  # never fight an autopilot's own return or landing
            return Alarm(
                self.name,
                Severity.WARN,
                f"Altitude {snap.altitude_m:.1f} meters is above the ceiling of "
                f"{self.ceiling_m:g} meters while the autopilot flies {mode}.",
            )
        return Alarm(
            self.name,
            Severity.WARN,
            f"Altitude {snap.altitude_m:.1f} meters is above the ceiling of "
            f"{self.ceiling_m:g} meters. Descending.",
            AlarmAction(ActionKind.DESCEND, distance_m=down),
        )
