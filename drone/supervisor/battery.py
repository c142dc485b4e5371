"""Battery: low → tell the operator and return home; critical → land (DESIGN §5)."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.phase import FLYING, Phase
from drone.vehicle import VehicleSnapshot


@dataclass
class BatteryMonitor:
    """Low: tell the operator and return home; critical: land.

    While the driver doubts the navdata (``snap.navdata_doubt``) the level is told but not acted
    on: a return home and a landing decided on a reading that may be forged would be flown
    blind, and the navdata monitor already holds the drone in a hover and asks the operator
    (:mod:`drone.supervisor.navdata`). The action follows as soon as the stream is trusted again
    if the level still holds. The readings reaching here already passed the driver's
    drain-and-sag check (drone/ardrone/plausibility.py), so a plausible critical level lands.
    """

    low_pct: float
    critical_pct: float
    period_s: float = 1.0
    hysteresis_pct: float = 2.0
    name: str = "battery"
    _level: int = 0  # 0 ok, 1 low reported, 2 critical reported
    _deferred: int = 0  # the level told while the navdata was in doubt, not yet acted on

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        if not snap.battery_known:
            return None  # early navdata carries no battery reading: no alarm on a missing value
        b = snap.battery_pct
        if b > self.low_pct + self.hysteresis_pct:
            self._level = 0
        elif self._level == 2 and b > self.critical_pct + self.hysteresis_pct:
            self._level = 1
        flying = phase in FLYING and snap.flying
        doubt = bool(snap.navdata_doubt)
        if self._deferred > self._level or not flying:
            self._deferred = 0
        if self._deferred and not doubt:
            level, self._deferred = self._deferred, 0
            return self._act(level, b, phase)
        if b <= self.critical_pct and self._level < 2:
            self._level = 2
            if flying and doubt:
                self._deferred = 2
                return Alarm(
                    self.name,
                    Severity.ALERT,
                    f"Battery reads critical at {b:.0f} percent, but I doubt the navdata, so I "
                    "am hovering. Say land to bring me down.",
                )
            if flying:
                return self._act(2, b, phase)
            return Alarm(
                self.name, Severity.ALERT, f"Battery critical at {b:.0f} percent. Do not take off."
            )
        if b <= self.low_pct and self._level < 1:
            self._level = 1
            if flying and phase is not Phase.RETURNING and doubt:
                self._deferred = 1
                return Alarm(
                    self.name,
                    Severity.WARN,
                    f"Battery reads low at {b:.0f} percent, but I doubt the navdata, so I am "
                    "not flying home on it.",
                )
            if flying and phase is not Phase.RETURNING:
                return self._act(1, b, phase)
            return Alarm(self.name, Severity.WARN, f"Battery low at {b:.0f} percent.")
        return None

    def _act(self, level: int, b: float, phase: Phase) -> Alarm | None:
        if level == 2:
            return Alarm(
                self.name,
                Severity.ALERT,
                f"Battery critical at {b:.0f} percent. Landing now.",
                AlarmAction(ActionKind.LAND),
            )
        if phase is Phase.RETURNING:
            return None
        return Alarm(
            self.name,
            Severity.WARN,
            f"Battery low at {b:.0f} percent. Returning home.",
            AlarmAction(ActionKind.RETURN_HOME),
        )
