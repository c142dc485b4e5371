"""More ANS monitors: the geofence of the world, estimator trouble, and navdata in doubt.

They follow :mod:`server.dialog.autonomic`'s contract (``name``, ``period_s``,
``check(snap, state, now) -> Alarm | None``, latched: told once when the condition starts and
once when it clears) and are added to every dialog manager's ANS by :func:`extra_monitors`.

* Geofence (DESIGN §5: "geofence of the world"): the estimated position leaves the world's
  flyable box while flying and localised -> alert and hover (the jog and the planner keep the
  drone inside; a breach means drift, e.g. wind, and the safe reaction is to stop).
* Estimator: flying without a position fix for ``lost_after_s``, or with a position standard
  deviation above ``max_sigma_m`` -> warn (marker tasks cannot be trusted; say so).
* Navdata (DESIGN §5: "implausible sensor data raises an alarm and hovers; it never lands a
  drone blind"): the driver doubts the navdata stream (``drone/ardrone/plausibility.py``:
  packets off the drone's numbering, battery readings no discharge explains) -> alert, hover,
  and ask the operator. Hover because it needs none of the doubted data: with PCMD's
  progressive flag cleared the AR.Drone holds its position with its own onboard sensors
  (Developer Guide §6.6), while the console's position loop, a return home or a landing
  decided on a battery reading would all act on data that may be forged. The operator, who can
  see the drone, decides; the drone's own firmware still guards its battery.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from server.dialog.autonomic import Alarm
from server.dialog.ports import VehicleSnapshot
from server.dialog.states import FLYING, State

# Beyond this the EKF's 1-sigma position error is larger than a marker's standoff distance
# (1 m, server/tasks/types.py GotoMarkerTask.standoff_m): a goto could end at the wrong marker.
MAX_SIGMA_M = 1.0
LOST_AFTER_S = 5.0  # a take-off and the first turn towards a marker fit comfortably in 5 s
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

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        if not snap.localised or state not in FLYING:
            return None
        m = FENCE_MARGIN_M
        outside = not (
            self.x_min - m <= snap.x_m <= self.x_max + m
            and self.y_min - m <= snap.y_m <= self.y_max + m
        )
        if outside and not self._out:
            self._out = True
            return Alarm(
                self.name,
                "alert",
                f"Geofence: I am outside the limits at x {snap.x_m:.1f}, y {snap.y_m:.1f} "
                "meters. Holding position; fly me back inside or land.",
                {"action": "hover"},
            )
        if not outside and self._out:
            self._out = False
            return Alarm(self.name, "info", "Back inside the geofence.")
        return None


@dataclass
class EstimatorMonitor:
    """Flying without a trustworthy position estimate: warn once; tell when it is back."""

    lost_after_s: float = LOST_AFTER_S
    max_sigma_m: float = MAX_SIGMA_M
    period_s: float = 0.5
    name: str = "estimator"
    _since: float | None = None
    _told: bool = False

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        bad = state in FLYING and (not snap.localised or snap.position_sigma_m > self.max_sigma_m)
        if not bad:
            self._since = None
            if self._told:
                self._told = False
                return Alarm(self.name, "info", "I know where I am again.")
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
                "warn",
                f"Estimator trouble: {why}. Fly me to where I can see a marker, or land.",
            )
        return None


DOUBT_TEXT = "Navdata inconsistent: sensor fault or spoofing"


@dataclass
class NavdataMonitor:
    """The driver doubts the navdata: alert, hover while flying, ask the operator; tell when the
    stream is consistent again (the drone stays where it is until the operator says). Told once
    per episode, and once more if the drone takes off while the doubt lasts."""

    period_s: float = 0.25
    name: str = "navdata"
    _told: str = ""  # "", "ground" (told, not flying) or "air" (told and hovered)

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        doubt = snap.navdata_doubt
        flying = state in FLYING and snap.flying
        if doubt and flying and self._told != "air":
            self._told = "air"
            return Alarm(
                self.name,
                "alert",
                f"{DOUBT_TEXT}: {doubt}. I am hovering and will not act on these readings. "
                "Say land to bring me down here, or tell me what to do.",
                {"action": "hover"},
            )
        if doubt and not self._told:
            self._told = "ground"
            return Alarm(
                self.name, "alert", f"{DOUBT_TEXT}: {doubt}. Check the drone before flying."
            )
        if not doubt and self._told:
            self._told = ""
            return Alarm(self.name, "info", "The navdata is consistent again.")
        return None


def extra_monitors(vehicle_port: Any, period_s: float) -> list[Any]:
    """The monitors above for a drone (the geofence only when its world has bounds)."""
    out: list[Any] = [EstimatorMonitor(period_s=period_s), NavdataMonitor(min(period_s, 0.25))]
    b = getattr(vehicle_port, "bounds", None)
    if b is not None:
        out.append(
            GeofenceMonitor(b.x_min, b.x_max, b.y_min, b.y_max, period_s=min(period_s, 0.25))
        )
    return out
