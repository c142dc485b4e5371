"""Temperature: the drone's own reading (navdata tag 21, :attr:`VehicleSnapshot.temperature_c`)
above ``warn_c`` → tell the operator; above ``land_c`` → land. The thresholds are settings
(``temperature_warn_c``, ``temperature_land_c``): the thermometer is the barometer's, inside the
hull beside the Li-Po battery, and most Li-Po cells are rated to discharge up to 60 °C, so the
defaults warn 5 °C under that and land at it."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.phase import FLYING, Phase
from drone.vehicle import VehicleSnapshot

WARN_C = 55.0
LAND_C = 60.0
HYSTERESIS_C = 2.0  # a reading's noise (±0.1 °C) and a short climb do not re-arm it


@dataclass
class TemperatureMonitor:
    """Warn once above ``warn_c``; land once above ``land_c`` while flying (tell on the ground).
    Re-armed when the reading falls ``hysteresis_c`` below the level told."""

    warn_c: float = WARN_C
    land_c: float = LAND_C
    period_s: float = 1.0
    hysteresis_c: float = HYSTERESIS_C
    name: str = "temperature"
    _level: int = 0  # 0 ok, 1 warned, 2 land told

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        t = snap.temperature_c
        if t is None:
            return None
        if t < self.warn_c - self.hysteresis_c:
            self._level = 0
        elif self._level == 2 and t < self.land_c - self.hysteresis_c:
            self._level = 1
        flying = phase in FLYING and snap.flying
        if t >= self.land_c and self._level < 2:
            self._level = 2
            if flying:
                return Alarm(
                    self.name,
                    Severity.ALERT,
                    f"Temperature {t:.0f} degrees inside the drone, at the {self.land_c:g} degree "
                    "limit of its battery. Landing now to let it cool.",
                    AlarmAction(ActionKind.LAND),
                )
            return Alarm(
                self.name,
                Severity.ALERT,
                f"Temperature {t:.0f} degrees inside the drone. Let it cool before flying.",
            )
        if t >= self.warn_c and self._level < 1:
            self._level = 1
            return Alarm(
                self.name,
                Severity.WARN,
                f"Temperature {t:.0f} degrees inside the drone and rising with the load: I will "
                f"land at {self.land_c:g}. Bring me back soon or lighten my work.",
            )
        return None
