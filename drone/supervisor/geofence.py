"""Geofence (DESIGN §5, "geofence of the world"): the estimated position leaves the world's
flyable box while flying and localised → alert and hover. The jog and the planner keep the
drone inside; a breach means drift (e.g. wind), and the safe reaction is to stop."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.phase import FLYING, Phase
from drone.vehicle import VehicleSnapshot

FENCE_MARGIN_M = 0.05  # estimate noise at the wall is not a breach


@dataclass
class GeofenceMonitor:
    """Estimated position outside the world's box while flying: alert, hover."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    period_s: float = 0.25
    name: str = "geofence"
    _out: bool = False

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        if not snap.localised or phase not in FLYING:
            return None
        m = FENCE_MARGIN_M
        outside = not (
            self.x_min - m <= snap.x <= self.x_max + m
            and self.y_min - m <= snap.y <= self.y_max + m
        )
        if outside and not self._out:
            self._out = True
            return Alarm(
                self.name,
                Severity.ALERT,
                f"Geofence: I am outside the limits at x {snap.x:.1f}, y {snap.y:.1f} "
                "meters. Holding position; fly me back inside or land.",
                AlarmAction(ActionKind.HOVER),
            )
        if not outside and self._out:
            self._out = False
            return Alarm(self.name, Severity.INFO, "Back inside the geofence.")
        return None
