"""Keep away from people (the papers' ANS example): no flight closer than the world's
``person_distance_m`` (drone/limits.py, default 2 m) to a person.

Three parts, all reading where the people are now (a person tracker; in simulation the
simulator's own, drone/sim/people.py):

* :meth:`KeepAway.target_refusal`: a command or plan whose target lies that close to a person
  is refused up front, with the reason (the task executor asks it while planning);
* :meth:`KeepAway.reroute`: legs whose straight line passes that close get a detour point
  beside the person, ``DETOUR_MARGIN_M`` further out (the executor asks it when a task starts);
* :class:`KeepAwayMonitor`: a person who comes that close to the hovering drone (they walk)
  makes it back off along the line from the person, to ``BACK_OFF_MARGIN_M`` beyond the
  distance, and say why; it holds its position when the limits leave no room to back off.
  A task in flight is not watched: its legs went round the people where they were when it
  started (a person who then walks into its way is a known gap).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from drone.control.pid import Setpoint
from drone.limits import FlightLimits
from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.phase import FLYING, Phase
from drone.vehicle import VehicleSnapshot

DETOUR_MARGIN_M = 0.5  # a detour passes this much beyond the distance (position error, drift)
BACK_OFF_MARGIN_M = (
    1.0  # backing off ends this much beyond it: a walker does not re-trigger at once
)
REARM_M = 0.25  # a hold with no room ends once the drone is this much beyond the distance
MAX_DETOURS = 6  # per leg (people in a row, or one walked round in steps); beyond: not flown


class Person(Protocol):
    """A tracked person (``drone.sim.people.PersonPose`` fits)."""

    @property
    def id(self) -> str: ...

    @property
    def x(self) -> float: ...

    @property
    def y(self) -> float: ...


@dataclass(frozen=True)
class Rerouted:
    """Legs with detours: ``origin[i]`` is the task's own leg index of leg ``i`` (None: a
    detour), ``around[i]`` whom a detour goes around ("" for the task's own legs)."""

    legs: list[Setpoint]
    origin: list[int | None]
    around: list[str]


def _closest_on_segment(
    a: tuple[float, float], b: tuple[float, float], p: tuple[float, float]
) -> tuple[float, float]:
    ax, ay = a
    dx, dy = b[0] - ax, b[1] - ay
    n2 = dx * dx + dy * dy
    f = 0.0 if n2 <= 0.0 else max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / n2))
    return ax + f * dx, ay + f * dy


@dataclass(frozen=True)
class KeepAway:
    """The keep-away distance of a world and where its people are."""

    people: Callable[[], Sequence[Person]]
    distance_m: float
    limits: FlightLimits | None = None

    def nearest(self, x: float, y: float) -> tuple[Person, float] | None:
        """The person nearest (x, y) and how far (None: nobody)."""
        found = [(p, math.hypot(p.x - x, p.y - y)) for p in self.people()]
        return min(found, key=lambda pd: pd[1]) if found else None

    def target_refusal(self, x: float, y: float) -> str | None:
        """Why a flight to (x, y) is refused (None: no person that close)."""
        near = self.nearest(x, y)
        if self.distance_m <= 0.0 or near is None or near[1] >= self.distance_m:
            return None
        who, d = near
        return (
            f"that would take me to {d:.1f} m from {who.id}, and I keep "
            f"{self.distance_m:g} m from people"
        )

    def _inside(self, x: float, y: float) -> tuple[float, float]:
        lim = self.limits
        if lim is None:
            return x, y
        m = lim.wall_margin_m
        return (
            min(max(x, lim.x_min + m), lim.x_max - m),
            min(max(y, lim.y_min + m), lim.y_max - m),
        )

    def _clear(self, x: float, y: float, of: Person) -> bool:
        return math.hypot(x - of.x, y - of.y) >= self.distance_m

    def _blocker(self, a: tuple[float, float], b: tuple[float, float]) -> Person | None:
        """The person the line a→b passes too close to, nearest its line first (None: none).
        One already too close at either end is not a detour's business: at the start the
        monitor backs off; a target too close was refused when planned."""
        worst: tuple[float, Person] | None = None
        for p in self.people():
            c = _closest_on_segment(a, b, (p.x, p.y))
            d = math.hypot(c[0] - p.x, c[1] - p.y)
            if d >= self.distance_m or not (self._clear(*a, p) and self._clear(*b, p)):
                continue
            if worst is None or d < worst[0]:
                worst = (d, p)
        return None if worst is None else worst[1]

    def _detour_point(
        self, a: tuple[float, float], b: tuple[float, float], p: Person
    ) -> tuple[float, float] | None:
        cx, cy = _closest_on_segment(a, b, (p.x, p.y))
        nx, ny = cx - p.x, cy - p.y
        n = math.hypot(nx, ny)
        if n < 1e-6:  # the line goes through the person: go round on its left
            dx, dy = b[0] - a[0], b[1] - a[1]
            n = math.hypot(dx, dy) or 1.0
            nx, ny = -dy, dx
        r = self.distance_m + DETOUR_MARGIN_M
        for side in (1.0, -1.0):
            x, y = self._inside(p.x + side * nx / n * r, p.y + side * ny / n * r)
            if self._clear(x, y, p):
                return x, y
        return None

    def reroute(
        self, start: tuple[float, float], legs: Sequence[Setpoint], *, loop: bool = False
    ) -> Rerouted | str:
        """``legs`` from ``start`` with detours round the people their lines pass too close
        to; or why they cannot be flown (no room to go round)."""
        out = Rerouted([], [], [])
        if self.distance_m <= 0.0 or not legs:
            out.legs.extend(legs)
            out.origin.extend(range(len(legs)))
            out.around.extend("" for _ in legs)
            return out
        hops = [(i, leg) for i, leg in enumerate(legs)]
        if loop and len(legs) > 1:
            hops.append((-1, legs[0]))  # the way back to the first leg, flown as a detour only
        a = start
        for i, leg in hops:
            b = (leg.x, leg.y)
            way = self._way_round(a, b)
            if isinstance(way, str):
                return way
            for (x, y), who in way:
                out.legs.append(Setpoint(x, y, leg.z, leg.yaw_rad))
                out.origin.append(None)
                out.around.append(who)
            if i >= 0:
                out.legs.append(leg)
                out.origin.append(i)
                out.around.append("")
            a = b
        return out

    def _way_round(
        self, a: tuple[float, float], b: tuple[float, float]
    ) -> list[tuple[tuple[float, float], str]] | str:
        """Detour points from a to b (each with whom it goes round), or why there are none: a
        sub-line that passes someone too close gets a point beside them, until none does."""
        points: list[tuple[tuple[float, float], str]] = []  # between a and b, in order
        for _ in range(MAX_DETOURS + 1):
            ends = [a, *(pt for pt, _ in points), b]
            for k in range(len(ends) - 1):
                who = self._blocker(ends[k], ends[k + 1])
                if who is not None:
                    break
            else:
                return points
            if len(points) == MAX_DETOURS:
                break
            via = self._detour_point(ends[k], ends[k + 1], who)
            if via is None:
                return (
                    f"the way passes closer than {self.distance_m:g} m to {who.id} and "
                    "there is no room to go round"
                )
            points.insert(k, (via, who.id))
        return f"the way passes too many people to keep {self.distance_m:g} m from each"

    def back_off_point(self, x: float, y: float, who: Person) -> tuple[float, float] | None:
        """Where to back off to from (x, y): along the line from ``who``, ``BACK_OFF_MARGIN_M``
        beyond the distance, inside the limits; None when the limits leave no such point."""
        dx, dy = x - who.x, y - who.y
        n = math.hypot(dx, dy)
        if n < 1e-6:
            dx, dy, n = 1.0, 0.0, 1.0
        r = self.distance_m + BACK_OFF_MARGIN_M
        candidates = [(dx / n, dy / n), (-dy / n, dx / n), (dy / n, -dx / n)]  # away, sideways
        for ux, uy in candidates:
            px, py = self._inside(who.x + ux * r, who.y + uy * r)
            if self._clear(px, py, who):
                return px, py
        return None


def _metres(v: float) -> str:
    return "1 meter" if v == 1.0 else f"{v:g} meters"


@dataclass
class KeepAwayMonitor:
    """A person closer than the distance to the hovering drone: back off and say why (hover,
    told once, when there is no room); again each time it hovers that close once more (the
    person followed). A flying task's legs were routed round the people when it started."""

    keep: KeepAway
    period_s: float = 0.25
    name: str = "people"
    _held: str = ""  # whom the drone holds for, with no room to back off ("" when none)

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None:
        d_keep = self.keep.distance_m
        near = self.keep.nearest(snap.x, snap.y)
        if phase not in FLYING or not snap.flying or not snap.localised or near is None:
            self._held = ""
            return None
        who, d = near
        if d > d_keep + REARM_M:
            self._held = ""
        if d >= d_keep or phase is not Phase.AIRBORNE or self._held == who.id:
            return None
        why = (
            f"{who.id} is {d:.1f} meters from me, closer than the {_metres(d_keep)} I keep "
            "from people"
        )
        to = self.keep.back_off_point(snap.x, snap.y, who)
        if to is None:
            self._held = who.id
            return Alarm(
                self.name,
                Severity.ALERT,
                f"{why}, and there is no room to back off. Holding position.",
                AlarmAction(ActionKind.HOVER),
            )
        return Alarm(
            self.name,
            Severity.ALERT,
            f"{why}. Backing off.",
            AlarmAction(ActionKind.BACK_OFF, to=(to[0], to[1], snap.z)),
        )
