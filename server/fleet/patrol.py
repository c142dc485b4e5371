"""The persistent-patrol experiment: the paper's mission flown in lockstep, measured, plotted.

``uav-console patrol --drones 2 --duration 3600`` builds a ``LockstepRig`` on the outdoor world
(real simulator, AR.Drone wire protocol in memory, EKF, the paper's PID, the task manager), one
LTM per drone, one CTM, and a station per drone that restores a landed drone (battery swap,
default 120 s, or charging at a rate: the world's pads then charge in the simulator). The
mission is the world's four waypoints (a 30 m square at 5 m near 36.367164 N, 127.363472 E)
given to the CTM as lat/lon/alt, as ``POST /missions`` would, with its handoff rule:
``predictive`` (the relief is on the route before the threshold) or ``reactive`` (the paper's:
the patrolling drone leaves at the threshold and the relief is sent then); ``--handoff both``
flies both on the same seed and reports them side by side. Coverage is measured from the
simulator's *true* positions: a drone covers the route while it flies (not in emergency) within
``corridor_m`` of the route at route height. The window starts when the route is first reached
(take-off and first transit are reported apart).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from server.fleet.ctm import CentralTaskManager
from server.fleet.geo import Enu, origin_of, to_geo
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import GeoWaypoint, Handoff, MissionRequest, Role
from server.fleet.planner import FlightModel, StationModel, coverage_bound

MAX_DRONES = 16
VISIT_RADIUS_M = 2.0  # a waypoint is visited when a drone passes within this (horizontally)
RECORD_PERIOD_S = 1.0


@dataclass(frozen=True)
class PatrolConfig:
    """Experiment knobs (defaults: the paper's mission with AR.Drone 2.0 batteries)."""

    drones: int = 2
    duration_s: float = 3600.0
    threshold: float = 0.30
    seed: int = 0
    # Tick: 0.1 s is the coarsest at which the paper PID still tracks (same coverage and gaps
    # as 0.05 s and 0.01 s, bench/fleet.py); the physics integrates its lags exactly.
    dt: float = 0.1
    flight_time_s: float | None = None  # battery: 100 % → 0 % hovering (None: 720 s)
    swap_s: float = 120.0
    charge_pct_s: float | None = None
    fail_at_s: float | None = None
    fail_kind: str = "emergency"  # emergency (motors cut) | link (drone link lost 60 s)
    ctm_period_s: float = 0.5
    status_period_s: float = 1.0
    lost_after_s: float = 3.0
    ctm_timeout_s: float = 15.0
    corridor_m: float = 2.5
    continuity: bool = True  # relief joins where the patrolling drone goes next (continuity.py)
    handoff: str = "predictive"  # or "reactive" (the paper's rule), server.fleet.messages.Handoff
    protocol: str = "ardrone"  # "mavlink": simulated PX4 quadrotors (issue 16)


def _f(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"


def station_positions(world: Any, n: int) -> list[Enu]:
    """The world's stations, then extra pads 1.5 m apart south of the home pad for more drones."""
    pads = [Enu(float(s.position[0]), float(s.position[1]), 0.0) for s in world.stations[:n]]
    for k in range(n - len(pads)):
        pads.append(Enu(-3.0 + 1.5 * (k % 5), -2.0 - 1.5 * (k // 5), 0.0))
    return pads


def charging_world(world: Any, pads: Sequence[Enu], charge_pct_s: float | None) -> Any:
    """``world`` with one station per pad, each charging at ``charge_pct_s`` (None: plain
    pads, the experiment's stations swap batteries instead)."""
    import dataclasses

    from drone.sim.world import Station

    stations = tuple(
        Station(f"home{k + 1}", (p.x, p.y, p.z), charge_pct_s=charge_pct_s or 0.0)
        for k, p in enumerate(pads)
    )
    return dataclasses.replace(world, stations=stations)


class StationService:
    """A home station: restores a drone that lands on it, with a battery swap after ``swap_s``
    or by charging (the AR.Drone simulator charges on the world's pads itself; a simulator
    without pads of its own, MAVLink's, is charged here)."""

    def __init__(self, sim: Any, position: Enu, model: StationModel) -> None:
        self.sim = sim
        self.position = position
        self.model = model
        self.landed_since: float | None = None
        self.restores = 0

    def step(self, now: float, dt: float) -> None:
        t = self.sim.truth
        here = math.hypot(t.x - self.position.x, t.y - self.position.y) < 1.5
        if t.flying or t.emergency or not here:
            self.landed_since = None
            return
        if self.landed_since is None:
            self.landed_since = now
        bat = self.sim.physics.battery
        if self.model.charge_pct_s is not None:
            if not hasattr(self.sim, "charging") and bat.pct < 100.0:
                bat.drain_to(bat.pct + self.model.charge_pct_s * dt)
        elif bat.pct < self.model.ready_pct and now - self.landed_since >= self.model.swap_s:
            bat.drain_to(100.0)
            self.restores += 1


class LockstepLink:
    """The CTM ↔ LTM transport in lockstep: direct calls, per-drone ``connected`` switch."""

    def __init__(self, ctm: CentralTaskManager, ltms: Sequence[LocalTaskManager]) -> None:
        self.ctm = ctm
        self.ltms = {x.name: x for x in ltms}
        self.connected = {x.name: True for x in ltms}
        self.sent = 0

    def status(self, ltm: LocalTaskManager, now: float) -> None:
        st = ltm.step(now)
        if st is not None and self.connected[ltm.name]:
            self.ctm.on_status(st, now)

    def ctm_step(self, now: float) -> None:
        for d in self.ctm.step(now):
            if not self.connected.get(d.drone, False):
                continue
            self.sent += 1
            ok, reason = self.ltms[d.drone].apply_plan(d.plan, now)
            self.ctm.on_plan_result(d.drone, d.plan.plan_id, ok, reason, now)
        for name, ltm in self.ltms.items():
            if self.connected[name]:
                ltm.heard_ctm(now)  # the /fleet/status heartbeat


@dataclass
class PatrolReport:
    config: PatrolConfig
    duration_s: float
    first_on_route_s: float | None
    coverage: float
    max_gap_s: float
    gaps: list[tuple[float, float]]
    handoffs: int
    replacements: int
    revisit_s: dict[str, dict[str, float | None]]
    handoff_revisit: list[dict[str, Any]]  # per handoff: intervals straddling it (truth)
    battery_min: dict[str, float]
    bound: dict[str, Any]
    wall_s: float
    cpu_s: float  # process CPU time: the speed on an unloaded core
    events: list[str]
    tracks: dict[str, list[tuple[float, float, float, float, float, str]]] = field(repr=False)
    route: list[tuple[float, float, float]] = field(repr=False, default_factory=list)

    @property
    def handoff_gap_s(self) -> float:
        """The longest coverage gap after the first drone reached the route: the gaps at
        handoffs (the reactive rule's, a late relief's)."""
        return max((b - a for a, b in self.gaps), default=0.0)

    @property
    def battery_lowest(self) -> float:
        """The lowest charge any drone reached."""
        return min(self.battery_min.values(), default=float("nan"))

    @property
    def realtime_factor(self) -> float:
        return self.duration_s / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def realtime_factor_cpu(self) -> float:
        return self.duration_s / self.cpu_s if self.cpu_s > 0 else math.inf

    def to_json(self) -> dict[str, Any]:
        return {
            "coverage": round(self.coverage, 5),
            "max_gap_s": round(self.max_gap_s, 2),
            "handoffs": self.handoffs,
            "replacements": self.replacements,
            "drones": self.config.drones,
            "duration_s": self.duration_s,
            "threshold": self.config.threshold,
            "first_on_route_s": self.first_on_route_s,
            "gaps": [[round(a, 2), round(b, 2)] for a, b in self.gaps],
            "revisit_s": self.revisit_s,
            "handoff_revisit": self.handoff_revisit,
            "continuity": self.config.continuity,
            "handoff": self.config.handoff,
            "handoff_gap_s": round(self.handoff_gap_s, 2),
            "battery_lowest_pct": round(self.battery_lowest, 1),
            "battery_min_pct": {k: round(v, 1) for k, v in self.battery_min.items()},
            "bound": self.bound,
            "fail_at_s": self.config.fail_at_s,
            "wall_s": round(self.wall_s, 2),
            "realtime_factor": round(self.realtime_factor, 1),
            "cpu_s": round(self.cpu_s, 2),
            "realtime_factor_cpu": round(self.realtime_factor_cpu, 1),
            "battery": {
                n: [[round(r[0], 1), round(r[4], 1)] for r in rows[:: max(1, len(rows) // 120)]]
                for n, rows in self.tracks.items()
            },
        }

    def format_text(self) -> str:
        c = self.config
        lines = [
            f"persistent patrol: {c.drones} drones, {self.duration_s:.0f} s simulated "
            f"in {self.wall_s:.1f} s wall ({self.realtime_factor:.0f}× real time; "
            f"{self.realtime_factor_cpu:.0f}× per CPU second), "
            f"handoff at {c.threshold:.0%} ({c.handoff})"
            + (f", failure ({c.fail_kind}) at {c.fail_at_s:.0f} s" if c.fail_at_s else ""),
            f"  first drone on the route after   {self.first_on_route_s or float('nan'):.1f} s",
            f"  coverage (from then on)          {100 * self.coverage:.2f} %",
            f"  longest gap                      {self.max_gap_s:.1f} s ({len(self.gaps)} gaps)",
            f"  handoffs                         {self.handoffs}",
            f"  replacements after failures      {self.replacements}",
            "  revisit time per waypoint (s)    mean / max",
        ]
        for wp, r in self.revisit_s.items():
            lines.append(
                f"    {wp:<30} {_f(r['mean'])} / {_f(r['max'])}  ({int(r['visits'] or 0)} visits)"
            )
        b = self.bound
        lines += [
            f"  drones persistent coverage needs {b['drones_needed']} "
            f"(bound: {b['on_route_s']:.0f} s on the route per {b['cycle_s']:.0f} s cycle; "
            f"best coverage with {c.drones}: "
            f"{100 * float(b['coverage_upper'].get(str(c.drones), 1.0)):.1f} %)",
            "  battery over time (%):",
        ]
        for name, rows in self.tracks.items():
            step = max(1, len(rows) // 12)
            pts = " ".join(f"{r[4]:.0f}" for r in rows[::step])
            lines.append(f"    {name}: {pts}   (min {self.battery_min[name]:.0f})")
        return "\n".join(lines)

    def plot(self, path: Path) -> None:
        """Tracks (map frame, route and stations) and batteries over time, as a PNG.

        Raises:
            RuntimeError: matplotlib (the ``report`` extra) is not installed.
        """
        try:
            import matplotlib
        except ImportError as exc:
            raise RuntimeError(
                "the patrol plot needs matplotlib: pip install 'uav-console[report]'"
            ) from exc

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5.5), dpi=100)
        rx = [p[0] for p in self.route] + [self.route[0][0]]
        ry = [p[1] for p in self.route] + [self.route[0][1]]
        ax1.plot(rx, ry, "k--", lw=1.5, label="route")
        for name, rows in self.tracks.items():
            line = ax1.plot([r[1] for r in rows], [r[2] for r in rows], lw=0.8, label=name)
            ax2.plot(
                [r[0] / 60 for r in rows],
                [r[4] for r in rows],
                color=line[0].get_color(),
                label=name,
            )
        ax1.set_aspect("equal")
        ax1.set_xlabel("east (m)")
        ax1.set_ylabel("north (m)")
        ax1.set_title("tracks (simulator truth)")
        ax1.legend(loc="upper right", fontsize=8)
        ax2.axhline(100 * self.config.threshold, color="grey", ls=":", label="handoff threshold")
        for a, b in self.gaps:
            ax2.axvspan(a / 60, b / 60, color="red", alpha=0.3)
        ax2.set_xlabel("time (min)")
        ax2.set_ylabel("battery (%)")
        ax2.set_ylim(0, 105)
        ax2.set_title(
            f"coverage {100 * self.coverage:.2f} %, longest gap {self.max_gap_s:.1f} s, "
            f"{self.handoffs} handoffs"
        )
        ax2.legend(loc="lower left", fontsize=8)
        fig.tight_layout()
        fig.savefig(path)
        plt.close(fig)


class PatrolExperiment:
    """Build the rig, CTM, LTMs and stations; ``run`` flies the mission and measures it."""

    def __init__(self, cfg: PatrolConfig) -> None:
        from drone.lockstep import LockstepRig
        from drone.sim.battery import FLIGHT_TIME_S
        from drone.sim.world import load_world
        from server.tasks.manager import TaskManager

        if not 1 <= cfg.drones <= MAX_DRONES:
            raise ValueError(f"--drones must be in 1..{MAX_DRONES}, got {cfg.drones}")
        if not cfg.duration_s > 0:
            raise ValueError(f"--duration must be > 0, got {cfg.duration_s}")
        try:
            self.handoff = Handoff(cfg.handoff)
        except ValueError:
            raise ValueError(
                f"--handoff must be reactive or predictive, got {cfg.handoff!r}"
            ) from None
        self.cfg = cfg
        pads = station_positions(load_world("outdoor"), cfg.drones)
        self.world = charging_world(load_world("outdoor"), pads, cfg.charge_pct_s)
        yaw = self.world.start.yaw_rad
        self.rig: Any
        if cfg.protocol == "mavlink":
            from drone.mavlink.lockstep import MavlinkLockstepRig

            self.rig = MavlinkLockstepRig(
                self.world, cfg.drones, dt=cfg.dt, starts=[(p.x, p.y, yaw) for p in pads]
            )
        else:
            self.rig = LockstepRig(
                self.world,
                n_drones=cfg.drones,
                seed=cfg.seed,
                camera=False,
                dt=cfg.dt,
                starts=[(p.x, p.y, yaw) for p in pads],
            )
        flight = cfg.flight_time_s or FLIGHT_TIME_S
        for sim in self.rig.sims:
            sim.physics.battery.flight_time_s = flight
        self.model = FlightModel.for_flight_time(flight)
        self.station_model = StationModel(swap_s=cfg.swap_s, charge_pct_s=cfg.charge_pct_s)
        self.origin = origin_of(self.world)
        self.ctm = CentralTaskManager(
            model=self.model,
            stations=self.station_model,
            lost_after_s=cfg.lost_after_s,
            corridor_m=cfg.corridor_m,
            origin=self.origin,
            world=self.world,
            continuity=cfg.continuity,
        )
        self.tasks = []
        self.ltms: list[LocalTaskManager] = []
        self.stations: list[StationService] = []
        for i, v in enumerate(self.rig.vehicles):
            tm = TaskManager(v, self.world, self.rig.clock)
            st = pads[i]
            ltm = LocalTaskManager(
                v.name,
                v,
                tm,
                st,
                origin=self.origin,
                period_s=cfg.status_period_s,
                ctm_timeout_s=cfg.ctm_timeout_s,
                model=self.model,
            )
            self.tasks.append(tm)
            self.ltms.append(ltm)
            self.stations.append(StationService(self.rig.sims[i], st, self.station_model))
        self.link = LockstepLink(self.ctm, self.ltms)
        self.hooks: list[Callable[[float], None]] = []  # tests: f(now) after each tick
        self._failed = False
        self._next_ctm = 0.0
        self._next_ltm = 0.0

    def mission_request(self) -> MissionRequest:
        """The paper's mission as ``POST /missions`` gets it: the world's waypoints in lat/lon."""
        assert self.origin is not None
        wps = []
        for w in self.world.waypoints:
            g = to_geo(Enu(*map(float, w.position)), self.origin)
            wps.append(GeoWaypoint(lat=g.lat_deg, lon=g.lon_deg, alt=g.alt_m))
        return MissionRequest(
            waypoints=wps, loop=True, handoff_threshold=self.cfg.threshold, handoff=self.handoff
        )

    def _tick(self, now: float, dt: float) -> None:
        for tm in self.tasks:
            tm.step(now)
        for s in self.stations:
            s.step(now, dt)
        if now + 1e-9 >= self._next_ltm:
            self._next_ltm += 0.2
            for ltm in self.ltms:
                self.link.status(ltm, now)
        if now + 1e-9 >= self._next_ctm:
            self._next_ctm += self.cfg.ctm_period_s
            self.link.ctm_step(now)
        cfg = self.cfg
        if cfg.fail_at_s is not None and not self._failed and now >= cfg.fail_at_s:
            self.fail_active(now)
        for h in self.hooks:
            h(now)

    def fail_active(self, now: float) -> str | None:
        """Make the patrolling drone fail (``fail_kind``); returns its name."""
        self._failed = True
        for ms in self.ctm.missions.values():
            if ms.active is not None:
                i = int(ms.active.removeprefix("uav")) - 1
                if self.cfg.fail_kind == "link":
                    self.rig.sims[i].inject_fault("link_loss", duration_s=60.0)
                else:
                    self.rig.sims[i].physics.cut_motors()
                self.ctm.event(now, f"[experiment] {ms.active} fails ({self.cfg.fail_kind})")
                return ms.active
        return None

    def run(self) -> PatrolReport:
        cfg, rig = self.cfg, self.rig
        wall0, cpu0 = time.perf_counter(), time.process_time()
        rig.wait_link()
        for ltm in self.ltms:
            ltm.configure_drone()
        rig.run(0.5)  # the config write reaches the drones
        t0 = rig.clock.now()
        mission = self.ctm.mission_from_request(self.mission_request(), t0)
        route = mission.route
        rig.add_stepper(self._tick)
        names = [v.name for v in rig.vehicles]
        tracks: dict[str, list[tuple[float, float, float, float, float, str]]] = {
            n: [] for n in names
        }
        first: float | None = None
        covered_prev = False
        gap_start: float | None = None
        gaps: list[tuple[float, float]] = []
        covered_s = 0.0
        inside = {(w, n): False for w in range(len(route)) for n in names}
        visits: dict[int, list[float]] = {w: [] for w in range(len(route))}
        next_rec = t0
        end = t0 + cfg.duration_s
        dt = rig.dt
        while rig.clock.now() < end - 1e-9:
            rig.step()
            now = rig.clock.now()
            covered = False
            for n, sim in zip(names, rig.sims, strict=True):
                t = sim.truth
                if not t.flying or t.emergency:
                    for w in range(len(route)):
                        inside[(w, n)] = False
                    continue
                p = Enu(t.x, t.y, t.z)
                if self.ctm.on_route(p, mission):
                    covered = True
                for w, wp in enumerate(route):
                    near = p.dist_xy(wp) <= VISIT_RADIUS_M and abs(p.z - wp.z) < 1.5
                    if near and not inside[(w, n)]:
                        visits[w].append(now)
                    inside[(w, n)] = near
            if covered and first is None:
                first = now
            if first is not None:
                if covered:
                    covered_s += dt
                    if gap_start is not None:
                        gaps.append((gap_start - t0, now - t0))
                        gap_start = None
                elif covered_prev or (gap_start is None and not covered):
                    gap_start = gap_start if gap_start is not None else now
            covered_prev = covered
            if now + 1e-9 >= next_rec:
                next_rec += RECORD_PERIOD_S
                for n, sim in zip(names, rig.sims, strict=True):
                    t = sim.truth
                    role = (
                        self.ctm.drones[n].role.value if n in self.ctm.drones else Role.IDLE.value
                    )
                    tracks[n].append((now - t0, t.x, t.y, t.z, t.battery_pct, role))
        if gap_start is not None:
            gaps.append((gap_start - t0, rig.clock.now() - t0))
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        window = (end - first) if first is not None else 0.0
        coverage = min(1.0, covered_s / window) if window > 0 else 0.0
        revisit: dict[str, dict[str, float | None]] = {}
        for w, ts in visits.items():
            label = self.world.waypoints[w].id if w < len(self.world.waypoints) else f"wp{w + 1}"
            g = mission.geo[w] if mission.geo else None
            if g:
                label += f" ({g[0]:.6f}, {g[1]:.6f})"
            d = [b - a for a, b in itertools.pairwise(ts)]
            revisit[label] = {
                "mean": round(sum(d) / len(d), 2) if d else None,  # None: fewer than 2 visits
                "max": round(max(d), 2) if d else None,
                "visits": float(len(ts)),
            }
        handoff_revisit = handoff_revisits(visits, self.ctm.missions[mission.id], t0)
        entry = route[self.ctm.entry_index(self.ltms[0].station, route)]
        bound = coverage_bound(
            self.ltms[0].station, entry, cfg.threshold, self.model, self.station_model
        ).as_dict()
        ms = self.ctm.missions[mission.id]
        return PatrolReport(
            config=cfg,
            duration_s=cfg.duration_s,
            first_on_route_s=None if first is None else first - t0,
            coverage=coverage,
            max_gap_s=max((b - a for a, b in gaps), default=0.0),
            gaps=gaps,
            handoffs=ms.handoffs,
            replacements=ms.replacements,
            revisit_s=revisit,
            handoff_revisit=handoff_revisit,
            battery_min={
                n: min((r[4] for r in rows), default=float("nan")) for n, rows in tracks.items()
            },
            bound=bound,
            wall_s=wall,
            cpu_s=cpu,
            events=[f"{t - t0:8.1f} {text}" for t, text in self.ctm.events],
            tracks=tracks,
            route=[(p.x, p.y, p.z) for p in route],
        )


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


def compare_text(reports: Sequence[PatrolReport]) -> str:
    """The handoff rules side by side (same seed, same everything else): the paper's reactive
    rule and the predictive one."""
    c = reports[0].config
    head = (
        f"handoff rules compared: {c.drones} drones, {c.duration_s:.0f} s simulated, seed "
        f"{c.seed}, handoff at {c.threshold:.0%}"
    )
    rows: list[tuple[str, list[Any], str]] = [
        ("", [r.config.handoff for r in reports], "{}"),
        ("coverage (%)", [100 * r.coverage for r in reports], "{:.2f}"),
        ("longest gap at a handoff (s)", [r.handoff_gap_s for r in reports], "{:.1f}"),
        ("gaps", [len(r.gaps) for r in reports], "{}"),
        ("handoffs", [r.handoffs for r in reports], "{}"),
        ("lowest battery (%)", [r.battery_lowest for r in reports], "{:.1f}"),
    ]
    lines = [head]
    for label, vals, fmt in rows:
        lines.append(f"  {label:<30}" + "".join(f"{fmt.format(v):>14}" for v in vals))
    return "\n".join(lines)


def run_patrol(cfg: PatrolConfig) -> PatrolReport:
    """Build and run one experiment."""
    return PatrolExperiment(cfg).run()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uav-console patrol", description=__doc__.split("\n")[0])
    p.add_argument("--drones", type=int, default=2)
    p.add_argument("--duration", type=float, default=3600.0, help="simulated seconds")
    p.add_argument("--threshold", type=float, default=0.30, help="handoff battery fraction")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--png", type=Path, default=None, help="write tracks and batteries here")
    p.add_argument("--fail-at", type=float, default=None, help="the patrolling drone fails at S")
    p.add_argument("--fail-kind", choices=("emergency", "link"), default="emergency")
    p.add_argument("--swap", type=float, default=120.0, help="station battery swap time (s)")
    p.add_argument("--charge-rate", type=float, default=None, help="charge at %%/s instead")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dt", type=float, default=0.1, help="lockstep tick (s)")
    p.add_argument("--events", action="store_true", help="also print the CTM's event log")
    p.add_argument("--protocol", choices=("ardrone", "mavlink"), default="ardrone")
    p.add_argument(
        "--handoff",
        choices=("predictive", "reactive", "both"),
        default="predictive",
        help="predictive: the relief is on the route before the threshold; reactive: the "
        "paper's rule, leave at the threshold and send the relief then; both: fly both on "
        "the same seed and report them side by side",
    )
    return p


def patrol_main(argv: Sequence[str]) -> int:
    """``uav-console patrol``; returns the exit status (2: bad arguments)."""
    args = _parser().parse_args(list(argv))
    if not 0.0 < args.threshold < 1.0:
        print("uav-console patrol: --threshold must be in (0, 1)", file=sys.stderr)
        return 2
    rules = ("reactive", "predictive") if args.handoff == "both" else (args.handoff,)
    try:
        exps = [
            PatrolExperiment(
                PatrolConfig(
                    drones=args.drones,
                    duration_s=args.duration,
                    threshold=args.threshold,
                    seed=args.seed,
                    dt=args.dt,
                    swap_s=args.swap,
                    charge_pct_s=args.charge_rate,
                    fail_at_s=args.fail_at,
                    fail_kind=args.fail_kind,
                    protocol=args.protocol,
                    handoff=rule,
                )
            )
            for rule in rules
        ]
    except ValueError as exc:
        print(f"uav-console patrol: {exc}", file=sys.stderr)
        return 2
    if len(exps) > 1:
        reports = [e.run() for e in exps]
        if args.json:
            print(json.dumps({r.config.handoff: r.to_json() for r in reports}))
        else:
            print(compare_text(reports))
        return 0
    report = exps[0].run()
    if args.png is not None:
        report.plot(args.png)
    if args.json:
        print(json.dumps(report.to_json()))
    else:
        print(report.format_text())
        if args.png is not None:
            print(f"  figure: {args.png}")
        if args.events:
            print("events:")
            print("\n".join("  " + e for e in report.events))
    return 0
