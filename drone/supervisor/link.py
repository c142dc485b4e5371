"""Link: no navdata → alert (the AR.Drone's own watchdog hovers it); tell when it is back."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import Alarm, Severity
from drone.supervisor.phase import Phase
from drone.vehicle import VehicleSnapshot


@dataclass
class LinkMonitor:
    """No navdata: alert; an autopilot (MAVLink) says what its own data-link failsafe does. In
    flight the AR.Drone's own watchdog hovers it, which the alarm says; on the ground there is
    nothing to hover and it says so."""

    period_s: float = 0.25
    name: str = "link"
    _lost: bool = False

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        if not snap.link_ok and not self._lost:
            self._lost = True
            failsafe = str(snap.extra.get("failsafe") or "")
            if failsafe:
                return Alarm(
                    self.name, Severity.ALERT, f"I lost the link to the drone. {failsafe}."
                )
            if not snap.flying:
                return Alarm(
                    self.name, Severity.ALERT, "I lost the link to the drone. It was on the ground."
                )
            return Alarm(
                self.name, Severity.ALERT, "I lost the link to the drone. It will hover on its own."
            )
        if snap.link_ok and self._lost:
            self._lost = False
            return Alarm(self.name, Severity.INFO, "The link to the drone is back.")
        return None
