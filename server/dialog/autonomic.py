"""ANS: autonomic monitors, each with its own period, that preempt voluntary tasks.

Each monitor looks at a :class:`VehicleSnapshot` and may raise an :class:`Alarm` (a sentence, a
level and optionally a command that preempts the task manager). Monitors latch: an alarm fires
once when its condition starts and re-arms only when the condition has cleared (with hysteresis
for the battery), so the operator is told once, not every period.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from server.dialog.ports import VehicleSnapshot
from server.dialog.states import FLYING, State


@dataclass(frozen=True)
class Alarm:
    monitor: str
    level: str  # info | warn | alert
    text: str
    action: Mapping[str, Any] | None = None


@dataclass
class BatteryMonitor:
    """Low: tell the operator and return home; critical: land (DESIGN §5).

    While the driver doubts the navdata (``snap.navdata_doubt``) the level is told but not acted
    on: a return home and a landing decided on a reading that may be forged would be flown
    blind, and the navdata monitor already holds the drone in a hover and asks the operator
    (server/dialog/monitors.py). The action follows as soon as the stream is trusted again if
    the level still holds. The readings reaching here already passed the driver's drain-and-sag
    check (drone/ardrone/plausibility.py), so a plausible critical level lands as it always has.
    """

    low_pct: float
    critical_pct: float
    period_s: float = 1.0
    hysteresis_pct: float = 2.0
    name: str = "battery"
    _level: int = 0  # 0 ok, 1 low reported, 2 critical reported
    _deferred: int = 0  # the level told while the navdata was in doubt, not yet acted on

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        if not snap.battery_known:
            return None  # early navdata carries no battery reading: no alarm on a missing value
        b = snap.battery_pct
        if b > self.low_pct + self.hysteresis_pct:
            self._level = 0
        elif self._level == 2 and b > self.critical_pct + self.hysteresis_pct:
            self._level = 1
        flying = state in FLYING and snap.flying
        doubt = bool(snap.navdata_doubt)
        if self._deferred > self._level or not flying:
            self._deferred = 0
        if self._deferred and not doubt:
            level, self._deferred = self._deferred, 0
            return self._act(level, b, state)
        if b <= self.critical_pct and self._level < 2:
            self._level = 2
            if flying and doubt:
                self._deferred = 2
                return Alarm(
                    self.name,
                    "alert",
                    f"Battery reads critical at {b:.0f} percent, but I doubt the navdata, so I "
                    "am hovering. Say land to bring me down.",
                )
            if flying:
                return self._act(2, b, state)
            return Alarm(
                self.name, "alert", f"Battery critical at {b:.0f} percent. Do not take off."
            )
        if b <= self.low_pct and self._level < 1:
            self._level = 1
            if flying and state is not State.RETURNING and doubt:
                self._deferred = 1
                return Alarm(
                    self.name,
                    "warn",
                    f"Battery reads low at {b:.0f} percent, but I doubt the navdata, so I am "
                    "not flying home on it.",
                )
            if flying and state is not State.RETURNING:
                return self._act(1, b, state)
            return Alarm(self.name, "warn", f"Battery low at {b:.0f} percent.")
        return None

    def _act(self, level: int, b: float, state: State) -> Alarm | None:
        if level == 2:
            return Alarm(
                self.name,
                "alert",
                f"Battery critical at {b:.0f} percent. Landing now.",
                {"action": "land"},
            )
        if state is State.RETURNING:
            return None
        return Alarm(
            self.name,
            "warn",
            f"Battery low at {b:.0f} percent. Returning home.",
            {"action": "return_home"},
        )


# MAVLink flight modes in which the autopilot itself climbs, returns or lands (issue 16).
AUTOPILOT_RETURN_MODES = ("AUTO.RTL", "AUTO.LAND", "RTL", "LAND", "SMART_RTL")


@dataclass
class AltitudeMonitor:
    """Above the ceiling: warn and descend back under it."""

    ceiling_m: float
    period_s: float = 0.5
    margin_m: float = 0.2
    name: str = "altitude"
    _over: bool = False

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        if not snap.flying or snap.altitude_m <= self.ceiling_m:
            if snap.altitude_m < self.ceiling_m - self.margin_m:
                self._over = False
            return None
        if self._over:
            return None
        self._over = True
        down = round(snap.altitude_m - self.ceiling_m + self.margin_m, 2)
        mode = snap.flight_mode
        if mode in AUTOPILOT_RETURN_MODES:  # never fight an autopilot's own return or landing
            return Alarm(
                self.name,
                "warn",
                f"Altitude {snap.altitude_m:.1f} meters is above the ceiling of "
                f"{self.ceiling_m:g} meters while the autopilot flies {mode}.",
            )
        return Alarm(
            self.name,
            "warn",
            f"Altitude {snap.altitude_m:.1f} meters is above the ceiling of "
            f"{self.ceiling_m:g} meters. Descending.",
            {"action": "move", "direction": "down", "distance": down},
        )


@dataclass
class LinkMonitor:
    """No navdata: alert; tell when it comes back. In flight the AR.Drone's own watchdog hovers
    it, which the alarm says; on the ground there is nothing to hover and it says so."""

    period_s: float = 0.25
    name: str = "link"
    _lost: bool = False

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        if not snap.link_ok and not self._lost:
            self._lost = True
            if snap.failsafe:  # an autopilot (MAVLink): its own data-link failsafe acts (issue 16)
                return Alarm(self.name, "alert", f"I lost the link to the drone. {snap.failsafe}.")
            if not snap.flying:
                return Alarm(
                    self.name, "alert", "I lost the link to the drone. It was on the ground."
                )
            return Alarm(
                self.name, "alert", "I lost the link to the drone. It will hover on its own."
            )
        if snap.link_ok and self._lost:
            self._lost = False
            return Alarm(self.name, "info", "The link to the drone is back.")
        return None


@dataclass
class MarkersLostMonitor:
    """While carrying out a task, no marker seen for ``after_s``: warn once; say when one is in
    sight again. It never claims a search: whether to search is the task manager's decision
    (it searches only when the estimate is no longer confident) and it says so itself, so the
    monitor is silent outside EXECUTING (issue 13 item 8), and while a GPS fix keeps the
    position (outdoors, far from the markers, that is the normal way to fly)."""

    after_s: float
    period_s: float = 0.5
    name: str = "markers"
    _since: float | None = None
    _told: bool = False

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None:
        if state is not State.EXECUTING or snap.gps:  # a GPS fix keeps the position outdoors
            self._since = None
            self._told = False
            return None
        if snap.visible_markers:
            told, self._since, self._told = self._told, None, False
            if told:
                ids = ", ".join(str(m) for m in snap.visible_markers)
                s = "s" if len(snap.visible_markers) > 1 else ""
                return Alarm(self.name, "info", f"I can see marker{s} {ids} again.")
            return None
        if self._since is None:
            self._since = now
        if not self._told and now - self._since >= self.after_s:
            self._told = True
            return Alarm(
                self.name, "warn", "I can no longer see any marker; flying on my own estimate."
            )
        return None


class Monitor:  # pragma: no cover - typing aid only
    name: str
    period_s: float

    def check(self, snap: VehicleSnapshot, state: State, now: float) -> Alarm | None: ...


@dataclass
class Autonomic:
    """Runs each monitor on its own period; :meth:`step` returns the alarms now due."""

    monitors: Sequence[Any]
    _due: dict[str, float] = field(default_factory=dict)
    _heard: bool = False  # the drone has answered at least once

    def __post_init__(self) -> None:
        # Periods are kept by name: a second monitor of the same name would never run.
        names = [m.name for m in self.monitors]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"ANS monitors need distinct names; repeated: {', '.join(dup)}")

    def step(self, snap: VehicleSnapshot, state: State, now: float) -> list[Alarm]:
        # Before the first navdata nothing is known (battery 0, link down): no false alarms.
        self._heard = self._heard or snap.link_ok
        if not self._heard:
            return []
        alarms: list[Alarm] = []
        for m in self.monitors:
            due = self._due.get(m.name, now)
            if now + 1e-9 < due:
                continue
            # absolute deadlines: no drift; skip missed periods rather than bursting
            nxt = due + m.period_s
            self._due[m.name] = nxt if nxt > now else now + m.period_s
            alarm = m.check(snap, state, now)
            if alarm is not None:
                alarms.append(alarm)
        # the most severe first: a critical battery outranks an altitude warning
        order = {"alert": 0, "warn": 1, "info": 2}
        return sorted(alarms, key=lambda a: order.get(a.level, 3))
