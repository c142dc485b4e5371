"""What the patrol experiment measures from the simulator's true positions, tick by tick:
route coverage and its gaps, waypoint visits and revisit times, each drone's track."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import Any

from server.fleet.continuity import VISIT_RADIUS_M
from server.fleet.geo import Enu

RECORD_PERIOD_S = 1.0
VISIT_HEIGHT_M = 1.5  # a visit is at route height ± this (the CTM's on-route rule)

Track = list[tuple[float, float, float, float, float, str]]  # t, x, y, z, battery %, role


class CoverageMeter:
    """Route coverage, its gaps and the waypoint visits.

    A drone covers the route while it flies (not in emergency) and ``on_route`` holds for its
    true position; a waypoint is visited when a drone comes within ``VISIT_RADIUS_M``
    (horizontally) of it at route height. The window opens when the route is first reached;
    gap times are from ``t0``.
    """

    def __init__(
        self,
        names: Sequence[str],
        route: Sequence[Enu],
        t0: float,
        dt: float,
        on_route: Callable[[Enu], bool],
    ) -> None:
        self.names = list(names)
        self.route = list(route)
        self.t0 = t0
        self.dt = dt
        self.on_route = on_route
        self.first: float | None = None  # when the route was first reached
        self.covered_s = 0.0
        self.gaps: list[tuple[float, float]] = []
        self.visits: dict[int, list[float]] = {w: [] for w in range(len(self.route))}
        self._inside = {(w, n): False for w in range(len(self.route)) for n in self.names}
        self._gap_start: float | None = None

    def observe(self, now: float, truths: Sequence[Any]) -> None:
        """One tick: each drone's true state (``flying``, ``emergency``, ``x``, ``y``, ``z``),
        in the order of ``names``."""
        covered = False
        for name, t in zip(self.names, truths, strict=True):
            if self._drone(now, name, t):
                covered = True
        self._account(now, covered)

    def _drone(self, now: float, name: str, t: Any) -> bool:
        """Whether drone ``name`` covers the route now; counts the waypoints it arrives at."""
        if not t.flying or t.emergency:
            for w in range(len(self.route)):
                self._inside[(w, name)] = False
            return False
        p = Enu(t.x, t.y, t.z)
        on = self.on_route(p)
        for w, wp in enumerate(self.route):
            near = p.dist_xy(wp) <= VISIT_RADIUS_M and abs(p.z - wp.z) < VISIT_HEIGHT_M
            if near and not self._inside[(w, name)]:
                self.visits[w].append(now)
            self._inside[(w, name)] = near
        return on

    def _account(self, now: float, covered: bool) -> None:
        if covered and self.first is None:
            self.first = now
        if self.first is None:
            return
        if covered:
            self.covered_s += self.dt
            if self._gap_start is not None:
                self.gaps.append((self._gap_start - self.t0, now - self.t0))
                self._gap_start = None
        elif self._gap_start is None:
            self._gap_start = now

    def close(self, now: float) -> None:
        """End the run: a gap still open ends ``now``."""
        if self._gap_start is not None:
            self.gaps.append((self._gap_start - self.t0, now - self.t0))
            self._gap_start = None

    def coverage(self, end: float) -> float:
        """The share of the window (first on the route → ``end``) with the route covered."""
        window = (end - self.first) if self.first is not None else 0.0
        return min(1.0, self.covered_s / window) if window > 0 else 0.0

    @property
    def first_on_route_s(self) -> float | None:
        return None if self.first is None else self.first - self.t0

    @property
    def max_gap_s(self) -> float:
        return max((b - a for a, b in self.gaps), default=0.0)


class TrackLog:
    """Each drone's true position, battery and role, every ``RECORD_PERIOD_S``."""

    def __init__(self, names: Sequence[str], t0: float) -> None:
        self.t0 = t0
        self.rows: dict[str, Track] = {n: [] for n in names}
        self._next = t0

    def observe(self, now: float, truths: Sequence[Any], role_of: Callable[[str], str]) -> None:
        """Record the tick when a period is due (``truths`` in the order of the names)."""
        if now + 1e-9 < self._next:
            return
        self._next += RECORD_PERIOD_S
        for (name, rows), t in zip(self.rows.items(), truths, strict=True):
            rows.append((now - self.t0, t.x, t.y, t.z, t.battery_pct, role_of(name)))

    def battery_min(self) -> dict[str, float]:
        """The lowest charge each drone reached."""
        return {n: min((r[4] for r in rows), default=float("nan")) for n, rows in self.rows.items()}


def revisit_table(
    visits: dict[int, list[float]], world: Any, geo: Sequence[tuple[float, float, float]] | None
) -> dict[str, dict[str, float | None]]:
    """Per waypoint (labelled by the world's id and lat/lon): mean and max revisit interval
    (None: fewer than 2 visits) and the number of visits."""
    out: dict[str, dict[str, float | None]] = {}
    for w, ts in visits.items():
        label = world.waypoints[w].id if w < len(world.waypoints) else f"wp{w + 1}"
        g = geo[w] if geo else None
        if g:
            label += f" ({g[0]:.6f}, {g[1]:.6f})"
        d = [b - a for a, b in itertools.pairwise(ts)]
        out[label] = {
            "mean": round(sum(d) / len(d), 2) if d else None,
            "max": round(max(d), 2) if d else None,
            "visits": float(len(ts)),
        }
    return out


def handoff_revisits(visits: dict[int, list[float]], ms: Any, t0: float) -> list[dict[str, Any]]:
    """Per handoff (and replacement) of ``ms``: the true revisit intervals that straddle it,
    against the median interval before it (the revisit-interval change a handoff costs)."""
    from server.fleet.continuity import CoverageTracker

    if ms.coverage is None:
        return []
    truth = CoverageTracker(ms.mission.route, t0)
    for k, ts in visits.items():
        truth.visits[k].extend(ts)
    out = []
    for h in ms.coverage.handoffs:
        row: dict[str, Any] = {"t": round(h.t - t0, 1), "kind": h.kind, "join": h.join_index}
        row.update(truth.straddling(h))
        out.append(row)
    return out
