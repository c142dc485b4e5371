"""The manual jog slowed or stopped near a wall, the floor or the ceiling: say why."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import Alarm, Severity
from drone.supervisor.phase import Phase
from drone.vehicle import VehicleSnapshot


@dataclass
class JogLimitMonitor:
    """Told once per kind of limiting ("slowed", "stopped"), again when it changes."""

    period_s: float = 0.25
    name: str = "jog_limit"
    _said: str = ""

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        why = snap.jog_limit
        if not why:
            self._said = ""
            return None
        kind = why.split(" ", 1)[0]  # "stopped" / "slowed": tell again when it changes
        if kind == self._said:
            return None
        self._said = kind
        return Alarm(self.name, Severity.WARN, f"Jog limited: {why}.")
