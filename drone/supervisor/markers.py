"""Markers out of sight while a task flies: warn once; say when one is in sight again."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import Alarm, Severity
from drone.supervisor.phase import Phase
from drone.vehicle import VehicleSnapshot

GPS_FRESH_S = 2.0  # a GPS fix this recent keeps the position (receivers give 1-5 fixes a second)


def gps_fresh(snap: VehicleSnapshot) -> bool:
    """A recent GPS fix keeps the position (outdoors, far from the markers)."""
    return snap.gps_age_s is not None and snap.gps_age_s <= GPS_FRESH_S


@dataclass
class MarkersLostMonitor:
    """While a task flies, no marker seen for ``after_s``: warn once; say when one is in sight
    again. It never claims a search: whether to search is the task executor's decision (it
    searches only when the estimate is no longer confident) and it says so itself, so the
    monitor is silent outside EXECUTING, and while a GPS fix keeps the position (outdoors, far
    from the markers, that is the normal way to fly)."""

    after_s: float
    period_s: float = 0.5
    name: str = "markers"
    _since: float | None = None
    _told: bool = False

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        if phase is not Phase.EXECUTING or gps_fresh(snap):
            self._since = None
            self._told = False
            return None
        seen = snap.marker_ids
        if seen:
            told, self._since, self._told = self._told, None, False
            if told:
                ids = ", ".join(str(m) for m in seen)
                s = "s" if len(seen) > 1 else ""
                return Alarm(self.name, Severity.INFO, f"I can see marker{s} {ids} again.")
            return None
        if self._since is None:
            self._since = now
        if not self._told and now - self._since >= self.after_s:
            self._told = True
            return Alarm(
                self.name,
                Severity.WARN,
                "I can no longer see any marker; flying on my own estimate.",
            )
        return None
