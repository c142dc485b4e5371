"""The estimator: flying without a trustworthy position (no fix, or too uncertain), and the
estimate disagreeing with the drone's own sensors (or restarted from them)."""

from __future__ import annotations

from dataclasses import dataclass

from drone.supervisor.alarms import Alarm, Severity
from drone.supervisor.phase import FLYING, Phase
from drone.vehicle import VehicleSnapshot

# Beyond this the EKF's 1-sigma position error is larger than a marker's standoff distance
# (1 m, server/tasks/goto.py GotoMarkerTask.standoff_m): a goto could end at the wrong marker.
MAX_SIGMA_M = 1.0
LOST_AFTER_S = 5.0  # a take-off and the first turn towards a marker fit comfortably in 5 s


@dataclass
class EstimatorMonitor:
    """Flying without a trustworthy position estimate: warn once; tell when it is back."""

    lost_after_s: float = LOST_AFTER_S
    max_sigma_m: float = MAX_SIGMA_M
    period_s: float = 0.5
    name: str = "estimator"
    _since: float | None = None
    _told: bool = False

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        bad = phase in FLYING and (not snap.localised or snap.position_sigma_m > self.max_sigma_m)
        if not bad:
            self._since = None
            if self._told:
                self._told = False
                return Alarm(self.name, Severity.INFO, "I know where I am again.")
            return None
        if self._since is None:
            self._since = now
        if not self._told and now - self._since >= self.lost_after_s:
            self._told = True
            why = (
                "I have no position fix"
                if not snap.localised
                else f"my position is uncertain by {snap.position_sigma_m:.1f} meters"
            )
            return Alarm(
                self.name,
                Severity.WARN,
                f"Estimator trouble: {why}. Fly me to where I can see a marker, or land.",
            )
        return None


@dataclass
class SensorAgreementMonitor:
    """The pose estimate disagrees with navdata (components gated out again and again), or the
    EKF had to restart a part of its state from navdata: tell the operator."""

    period_s: float = 0.25
    name: str = "estimator_sensors"
    _told: bool = False
    _reinits: int = 0

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        parts = ", ".join(snap.estimator_disagreement)
        if snap.estimator_reinits > self._reinits:
            self._reinits = snap.estimator_reinits
            self._told = bool(parts)
            return Alarm(
                self.name,
                Severity.ALERT,
                "My position estimate disagreed with the drone's own sensors; I reset it from "
                "them. Watch the drone.",
            )
        if parts and not self._told:
            self._told = True
            return Alarm(
                self.name,
                Severity.ALERT,
                f"My position estimate disagrees with the drone's sensors ({parts}).",
            )
        if not parts:
            self._told = False
        return None
