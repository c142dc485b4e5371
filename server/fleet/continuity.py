"""Handoff continuity and live coverage of a patrol route (CTANS), sans-I/O.

Two jobs, both pure functions of the LTM statuses the CTM already receives:

* **Where a relief joins** (:func:`choose_join`). The CTM locates the patrolling drone on the
  route (:func:`locate`: arc length along the polyline), predicts when it will reach each
  waypoint ahead of it (from the lap time observed so far), and sends the relief to the *first*
  waypoint it can reach before the patrolling drone does: the relief continues the sequence
  exactly where the tired drone would have gone next, so the patrol's progress carries over.
  (A relief entering at the waypoint nearest its own station, wherever the tired drone was,
  would fly the stretch between the two twice, and the waypoints behind the entry would wait up
  to a whole lap longer at every handoff.) The tired drone is released
  once it has flown the waypoints before the join (:func:`owes_waypoints`), not merely when
  the relief reaches the route: the relief's arrival is a prediction. After a failure there is no
  drone to meet; the replacement goes to the waypoint after the lost drone's last known
  position, the one that has waited longest.
* **Live coverage** (:class:`CoverageTracker`). Per waypoint: when it was last visited, the
  intervals between visits; the longest wait so far (a finished interval or the wait still
  open); and at every handoff the interval of each waypoint that straddles it, against the
  median interval before it, which is the revisit-interval change a handoff costs.
* **Route coverage** (:class:`RouteCoverage`). The share of time a drone flies on the route
  (within the CTM's corridor, at route height) from the moment one first reached it, and the
  coverage gaps (the route empty): the figures ``uav-console patrol`` measures from the
  simulator's truth, here from the drones' reported positions.

A waypoint is *visited* when a drone of the mission passes within ``visit_radius_m``
(horizontally, the same 2 m the patrol experiment measures coverage with) at route height.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections import deque
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

from server.fleet.geo import Enu

VISIT_RADIUS_M = 2.0  # horizontally; experiments/patrol counts its visits with it
MIN_VISIT_RADIUS_M = 1.0  # the fleet plan's arrival tolerance (FlightPlan.tolerance_m)
VISIT_HEIGHT_M = 1.5  # at route height ± this (the CTM's on-route rule)
MAX_VISITS = 512  # per waypoint: hours of patrol at a minute a lap


@dataclass(frozen=True)
class RoutePosition:
    """Where a point lies on a route: on segment ``segment`` (waypoint ``segment`` to the
    next), ``fraction`` of the way along it, ``s_m`` metres of arc from waypoint 0."""

    segment: int
    fraction: float
    s_m: float
    off_route_m: float

    def next_index(self, n: int) -> int:
        """The waypoint this point is flying towards."""
        return (self.segment + 1) % n


def perimeter_m(route: Sequence[Enu], loop: bool) -> float:
    """Horizontal length of the route (closed when ``loop``)."""
    n = len(route)
    legs = n if loop else n - 1
    return sum(route[i].dist_xy(route[(i + 1) % n]) for i in range(max(legs, 0)))


def locate(p: Enu, route: Sequence[Enu], loop: bool) -> RoutePosition:
    """Project ``p`` horizontally onto the route polyline (closed when ``loop``)."""
    n = len(route)
    if n == 1:
        return RoutePosition(0, 0.0, 0.0, p.dist_xy(route[0]))
    legs = n if loop else n - 1
    best: RoutePosition | None = None
    s0 = 0.0
    for i in range(legs):
        a, b = route[i], route[(i + 1) % n]
        dx, dy = b.x - a.x, b.y - a.y
        seg = math.hypot(dx, dy)
        t = 0.0 if seg == 0 else max(0.0, min(1.0, ((p.x - a.x) * dx + (p.y - a.y) * dy) / seg**2))
        d = math.hypot(p.x - (a.x + t * dx), p.y - (a.y + t * dy))
        if best is None or d < best.off_route_m - 1e-9:
            best = RoutePosition(i, t, s0 + t * seg, d)
        s0 += seg
    assert best is not None
    return best


def arc_ahead_m(pos: RoutePosition, k: int, route: Sequence[Enu], loop: bool) -> float:
    """Metres along the route from ``pos`` forward to waypoint ``k`` (wrapping when looping)."""
    n = len(route)
    total = perimeter_m(route, loop)
    s_k = sum(route[i].dist_xy(route[i + 1]) for i in range(k)) if k else 0.0
    ahead = s_k - pos.s_m
    if ahead <= 1e-6 and loop and total > 0:
        ahead += total
    return max(ahead, 0.0) if n > 1 else 0.0


@dataclass(frozen=True)
class JoinPoint:
    """Where and when a relief meets the patrol: waypoint ``index``, the relief there after
    ``relief_eta_s``, the patrolling drone after ``active_eta_s`` (None: nobody to meet)."""

    index: int
    relief_eta_s: float
    active_eta_s: float | None
    point: Enu | None = None  # enter the route here, on the leg to waypoint ``index``
    after: int | None = None  # the waypoint the patrolling drone was flying to (None: nobody)


def choose_join(
    route: Sequence[Enu],
    loop: bool,
    relief_eta_s: Sequence[float],
    active: Enu | None,
    lap_s: float,
    *,
    last_known: Enu | None = None,
) -> JoinPoint:
    """The waypoint a relief should join the route at (see the module docstring).

    Args:
        route: the mission's waypoints, in flying order.
        loop: whether the route is closed.
        relief_eta_s: per waypoint, the relief's time from dispatch to arrival there.
        active: the patrolling drone's position, or None when there is none.
        lap_s: the time one lap takes (observed, or the model's estimate).
        last_known: with no active drone, the last position of the one that was lost.
    """
    n = len(route)
    ref = active if active is not None else last_known
    if ref is None:
        k = min(range(n), key=lambda i: relief_eta_s[i])
        return JoinPoint(k, relief_eta_s[k], None)
    pos = locate(ref, route, loop)
    nxt = _flying_to(pos, n, loop)
    if active is None:
        return JoinPoint(nxt, relief_eta_s[nxt], None)
    total = perimeter_m(route, loop)
    speed = total / lap_s if lap_s > 0 and total > 0 else 0.0
    fallback: JoinPoint | None = None
    for j in range(n):
        k = (nxt + j) % n
        t_active = arc_ahead_m(pos, k, route, loop) / speed if speed > 0 else math.inf
        join = JoinPoint(k, relief_eta_s[k], t_active, after=nxt)
        if t_active >= relief_eta_s[k]:
            return join
        # none reachable in time within a lap: the smallest lateness
        if fallback is None or relief_eta_s[k] - t_active < (
            fallback.relief_eta_s - (fallback.active_eta_s or 0.0)
        ):
            fallback = join
    assert fallback is not None
    return fallback


def _flying_to(pos: RoutePosition, n: int, loop: bool) -> int:
    """The waypoint a drone at ``pos`` flies to next (an open route's last at its end)."""
    return pos.next_index(n) if loop or pos.segment + 1 < n else n - 1


def owes_waypoints(
    route: Sequence[Enu],
    loop: bool,
    join: JoinPoint,
    active: Enu,
    visited: Collection[int] = (),
) -> bool:
    """Whether the patrolling drone, now at ``active``, has yet to fly a waypoint before the
    relief's join that nobody has visited since the relief was sent (``visited``): one from
    ``join.after`` (where it was flying then) up to the one before ``join.index``.

    The join is chosen from *predicted* arrivals; the relief's comes from the flight model and
    may be seconds early (it reaches the route's corridor before the waypoint, and a faster
    patrol, e.g. with the GPS arrival radius of ``server.fleet.accuracy``, shifts which waypoint
    is chosen). A handoff that sent the tired drone home as soon as the relief was on the route
    would then leave the waypoints between the two unvisited for a lap more: the CTM hands over
    once this is false (the tired drone is on the leg into the join or past it, or the
    waypoints it had left were visited, e.g. by the relief on its way in).
    """
    if join.after is None or join.active_eta_s is None:
        return False  # nobody to meet (first drone, replacement) or no continuity
    n = len(route)
    owed: list[int] = []
    k = join.after
    while k != join.index and len(owed) < n:
        owed.append(k)
        k = (k + 1) % n
    nxt = _flying_to(locate(active, route, loop), n, loop)
    if nxt not in owed:
        return False  # on the leg into the join, or past it
    return any(w not in visited for w in owed[owed.index(nxt) :])


def visit_radius(route: Sequence[Enu], wanted: float = VISIT_RADIUS_M) -> float:
    """``wanted``, shrunk to half the closest spacing of waypoints (indoors they are 1.5 m
    apart: one pass must not count as a visit of its neighbours) but never under the plan's
    arrival tolerance."""
    gaps = [a.dist_xy(b) for a, b in itertools.pairwise(route)]
    if not gaps:
        return wanted
    return max(MIN_VISIT_RADIUS_M, min(wanted, 0.5 * min(gaps)))


def entry_on_leg(route: Sequence[Enu], loop: bool, k: int, p: Enu) -> Enu:
    """The point of the leg that ends at waypoint ``k`` nearest ``p`` (horizontally), at the
    leg's height there: where a replacement standing at ``p`` reaches that leg first."""
    n = len(route)
    if n == 1 or (k == 0 and not loop):
        return route[k]
    a, b = route[(k - 1) % n], route[k]
    dx, dy = b.x - a.x, b.y - a.y
    seg2 = dx * dx + dy * dy
    t = 0.0 if seg2 == 0 else max(0.0, min(1.0, ((p.x - a.x) * dx + (p.y - a.y) * dy) / seg2))
    return Enu(a.x + t * dx, a.y + t * dy, a.z + t * (b.z - a.z))


@dataclass
class HandoffRecord:
    """One handoff (or replacement) and the revisit intervals that straddle it."""

    t: float  # when the relief reached the route (the tired drone may leave later)
    relieved: str
    relief: str
    join_index: int
    kind: str = "handoff"  # handoff | replacement | resume (after the operator's pause)


@dataclass
class RouteCoverage:
    """Time with a drone on the route, from samples ``(covered, now)`` at the CTM's rate.

    Each interval between two samples counts as the later sample says (as the lockstep
    experiment counts each tick). The window opens at the first covered sample.
    """

    first_t: float | None = None
    last_t: float | None = None
    covered_s: float = 0.0
    gap_start: float | None = None
    gaps: int = 0
    longest_gap_s: float = 0.0

    def sample(self, covered: bool, now: float) -> None:
        """One look at the route: is a drone on it now?"""
        if self.first_t is None:
            if covered:
                self.first_t = self.last_t = now
            return
        assert self.last_t is not None
        if now < self.last_t:
            return  # never count time backwards
        dt = now - self.last_t
        self.last_t = now
        if covered:
            self.covered_s += dt
            if self.gap_start is not None:
                self._close_gap(now)
        elif self.gap_start is None:
            self.gap_start = now - dt

    def _close_gap(self, now: float) -> None:
        assert self.gap_start is not None
        self.gaps += 1
        self.longest_gap_s = max(self.longest_gap_s, now - self.gap_start)
        self.gap_start = None

    def window_s(self) -> float:
        """Seconds since a drone first reached the route (up to the latest sample)."""
        if self.first_t is None or self.last_t is None:
            return 0.0
        return self.last_t - self.first_t

    def coverage(self) -> float | None:
        """Share of the window with a drone on the route (None before one reached it)."""
        w = self.window_s()
        if self.first_t is None:
            return None
        return 1.0 if w <= 0 else min(1.0, self.covered_s / w)

    def longest(self) -> float:
        """The longest gap, the one still open included."""
        open_s = 0.0
        if self.gap_start is not None and self.last_t is not None:
            open_s = self.last_t - self.gap_start
        return max(self.longest_gap_s, open_s)

    def as_dict(self, started_t: float) -> dict[str, Any]:
        cov = self.coverage()
        return {
            "coverage": None if cov is None else round(cov, 5),
            "coverage_pct": None if cov is None else round(100.0 * cov, 2),
            "window_s": round(self.window_s(), 1),
            "covered_s": round(self.covered_s, 1),
            "longest_gap_s": round(self.longest(), 1),
            "gaps": self.gaps + (1 if self.gap_start is not None else 0),
            "first_on_route_s": (
                None if self.first_t is None else round(self.first_t - started_t, 1)
            ),
        }


@dataclass
class CoverageTracker:
    """Visits of one route's waypoints, from drone positions (see the module docstring)."""

    route: tuple[Enu, ...]
    started_t: float
    visit_radius_m: float = VISIT_RADIUS_M
    visits: list[deque[float]] = field(default_factory=list)
    handoffs: list[HandoffRecord] = field(default_factory=list)
    route_coverage: RouteCoverage = field(default_factory=RouteCoverage)
    _inside: dict[tuple[str, int], bool] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.visits:
            self.visits = [deque(maxlen=MAX_VISITS) for _ in self.route]
        self.visit_radius_m = visit_radius(self.route, self.visit_radius_m)

    def observe(self, name: str, p: Enu, flying: bool, now: float) -> None:
        """One position report of a drone on this mission."""
        for k, wp in enumerate(self.route):
            near = (
                flying and p.dist_xy(wp) <= self.visit_radius_m and abs(p.z - wp.z) < VISIT_HEIGHT_M
            )
            if near and not self._inside.get((name, k), False):
                self.visits[k].append(now)
            self._inside[(name, k)] = near

    def forget(self, name: str) -> None:
        """A drone left the mission: its next pass counts as a new visit."""
        for k in range(len(self.route)):
            self._inside.pop((name, k), None)

    def handoff(self, t: float, relieved: str, relief: str, join: int, kind: str) -> None:
        self.handoffs.append(HandoffRecord(t, relieved, relief, join, kind))

    # ------------------------------------------------------------------ measures
    def intervals(self, k: int) -> list[float]:
        return [b - a for a, b in itertools.pairwise(self.visits[k])]

    def lap_s(self) -> float | None:
        """The median revisit interval over all waypoints (one lap), once one is known."""
        d = [x for k in range(len(self.route)) for x in self.intervals(k)]
        return statistics.median(d) if d else None

    def since_last_s(self, k: int, now: float) -> float:
        """Seconds since waypoint ``k`` was last visited (since the start if never)."""
        v = self.visits[k]
        return now - (v[-1] if v else self.started_t)

    def longest_gap_s(self, now: float) -> float:
        """The longest any waypoint has waited for a visit so far (finished or still open)."""
        best = 0.0
        for k in range(len(self.route)):
            d = self.intervals(k)
            best = max([best, *d])
            if self.visits[k]:  # before a first visit the drones are still flying out
                best = max(best, self.since_last_s(k, now))
        return best

    def straddling(self, rec: HandoffRecord) -> dict[str, float | None]:
        """The revisit intervals that span ``rec`` against the median interval before it."""
        spans: list[float] = []
        before: list[float] = []
        for k in range(len(self.route)):
            v = list(self.visits[k])
            before += [b - a for a, b in itertools.pairwise(v) if b <= rec.t]
            prev = [x for x in v if x <= rec.t]
            nxt = [x for x in v if x > rec.t]
            if prev and nxt:
                spans.append(nxt[0] - prev[-1])
        base = statistics.median(before) if before else None
        worst = max(spans) if spans else None
        return {
            "baseline_s": None if base is None else round(base, 2),
            "straddle_max_s": None if worst is None else round(worst, 2),
            "straddle_median_s": None if not spans else round(statistics.median(spans), 2),
            "ratio": None if base is None or worst is None else round(worst / base, 3),
        }

    def as_dict(self, now: float) -> dict[str, Any]:
        """JSON-ready live coverage (``GET /missions/{id}`` ``coverage``, ``/fleet/status``)."""
        wps = []
        for k, wp in enumerate(self.route):
            d = self.intervals(k)
            wps.append(
                {
                    "index": k,
                    "x": round(wp.x, 2),
                    "y": round(wp.y, 2),
                    "z": round(wp.z, 2),
                    "visits": len(self.visits[k]),
                    "since_last_s": round(self.since_last_s(k, now), 1),
                    "visited": bool(self.visits[k]),
                    "max_interval_s": round(max(d), 1) if d else None,
                }
            )
        lap = self.lap_s()
        return {
            "waypoints": wps,
            "longest_gap_s": round(self.longest_gap_s(now), 1),
            "lap_s": None if lap is None else round(lap, 1),
            "route": self.route_coverage.as_dict(self.started_t),
            "handoffs": [
                {
                    "t": round(h.t, 1),
                    "kind": h.kind,
                    "relieved": h.relieved,
                    "relief": h.relief,
                    "join_index": h.join_index,
                    **self.straddling(h),
                }
                for h in self.handoffs[-20:]
            ],
        }
