"""Fleet benchmarks; prints tables of medians and ratios.

Table 1, persistent patrol in lockstep (PatrolExperiment: simulator, wire protocol, EKF, PID,
task managers, LTMs, CTM), simulated seconds per wall second for 2, 4 and 8 drones; baseline:
the bare LockstepRig with the same drones hovering (no fleet layer), measured in the same run,
so the ratio is the cost of the fleet layer (task managers, LTMs with GPS aiding, CTM, and the
simulator's GPS navdata option, which the bare rig does not request). Wall-clock figures on a
shared machine vary; the CPU-time column (simulated seconds per CPU second) does not. A row at
dt = 0.05 s shows the tick's effect on speed and coverage (target: ≥ 60× real time, 2 drones).

Table 2, the CTM alone with 100 simulated LTMs reporting at 1 Hz (statuses from a kinematic
stand-in, since the CTM only sees statuses): CPU seconds per simulated second, and the latency
of one decision round (median and p99); baseline: ingesting the statuses without deciding.

Table 3, handoff continuity: three drones, the patrolling one fails (motors cut) a
third of the way in, flown twice in the same run, with the relief joining at the waypoint
nearest its station (before, the baseline) and where the patrolling drone goes next (after).
Coverage and longest coverage gap as ``uav-console patrol`` measures them, and the revisit
interval at each handoff: per handoff the longest true revisit interval of any waypoint that
spans it, against the median interval before it (ratio 1.0: a handoff costs nothing). Full run:
an hour with the real battery (the README's 99.65 %, 12.7 s row); ``--quick``: 300 s with a
150 s battery.

Usage: ``python bench/fleet.py [--quick] [--repeats N] [--seconds S] [--only continuity]``.
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from experiments.patrol import PatrolConfig, PatrolExperiment
from server.fleet.ctm import CentralTaskManager
from server.fleet.geo import Enu
from server.fleet.messages import LtmStatus
from server.fleet.stations import station_positions


def bare_rig_rtf(n: int, seconds: float, dt: float) -> float:
    world = load_world("outdoor")
    pads = station_positions(world, n)
    rig = LockstepRig(
        world, n_drones=n, camera=False, dt=dt, starts=[(p.x, p.y, 0.0) for p in pads]
    )
    rig.takeoff_all()
    t0, s0 = time.perf_counter(), rig.clock.now()
    rig.run(seconds)
    return (rig.clock.now() - s0) / (time.perf_counter() - t0)


def patrol_run(n: int, seconds: float, dt: float) -> tuple[float, float, float, float]:
    rep = PatrolExperiment(PatrolConfig(drones=n, duration_s=seconds, dt=dt)).run()
    return rep.realtime_factor, rep.coverage, rep.max_gap_s, rep.realtime_factor_cpu


def table_patrol(repeats: int, seconds: float) -> None:
    print(f"patrol in lockstep, {seconds:.0f} s simulated, median of {repeats}")
    print(
        f"{'drones':>6} {'dt s':>5} {'fleet RTF':>10} {'bare rig RTF':>13} {'ratio':>6} "
        f"{'RTF per CPU s':>13} {'coverage %':>10} {'max gap s':>9}"
    )
    for n, dt in ((2, 0.1), (4, 0.1), (8, 0.1), (2, 0.05)):
        runs = [patrol_run(n, seconds, dt) for _ in range(repeats)]
        rtf = statistics.median(r[0] for r in runs)
        base = statistics.median(bare_rig_rtf(n, min(seconds, 60.0), dt) for _ in range(repeats))
        cov = statistics.median(r[1] for r in runs)
        gap = statistics.median(r[2] for r in runs)
        cpu_rtf = statistics.median(r[3] for r in runs)
        print(
            f"{n:>6} {dt:>5.2f} {rtf:>9.0f}× {base:>12.0f}× {rtf / base:>6.2f} "
            f"{cpu_rtf:>12.0f}× {100 * cov:>10.2f} {gap:>9.1f}"
        )


def fake_status(name: str, i: int, t: float, station: Enu, plan_id: int, kind: str) -> LtmStatus:
    """A kinematic stand-in LTM: flies a circle when it has a patrol plan, drains 1/7.2 %/s."""
    flying = kind in ("patrol", "return")
    bat = max(0.0, 100.0 - (t % 720.0) / 7.2) if flying else 100.0
    a = 0.1 * t + i
    x, y, z = (
        (station.x + 10 * math.cos(a), station.y + 10 * math.sin(a), 5.0)
        if flying
        else (station.x, station.y, 0.0)
    )
    return LtmStatus(
        name=name,
        t=t,
        seq=int(t),
        x=x,
        y=y,
        z=z,
        yaw_deg=0.0,
        lat=0.0,
        lon=0.0,
        battery_pct=bat,
        flying=flying,
        state="FLYING" if flying else "LANDED",
        link_ok=True,
        emergency=False,
        station=station,
        plan_id=plan_id,
    )


def table_ctm(repeats: int, seconds: float, n_ltm: int = 100, n_missions: int = 10) -> None:
    print(
        f"\nCTM with {n_ltm} simulated LTMs at 1 Hz, {n_missions} missions, "
        f"{seconds:.0f} s simulated, median of {repeats}"
    )
    rng = random.Random(0)
    rows = []
    for _ in range(repeats):
        ctm = CentralTaskManager()
        for _k in range(n_missions):
            cx, cy = rng.uniform(-40, 40), rng.uniform(-40, 40)
            ctm.add_mission(
                [
                    Enu(cx + dx, cy + dy, 5.0)
                    for dx, dy in ((-10, -10), (10, -10), (10, 10), (-10, 10))
                ],
                now=0.0,
            )
        stations = [Enu(rng.uniform(-50, 50), rng.uniform(-50, 50), 0.0) for _ in range(n_ltm)]
        plans = {f"uav{i + 1}": (0, "none") for i in range(n_ltm)}
        lat: list[float] = []
        ingest = 0.0
        cpu0 = time.process_time()
        for t in range(int(seconds)):
            t0 = time.perf_counter()
            for i in range(n_ltm):
                name = f"uav{i + 1}"
                pid, kind = plans[name]
                ctm.on_status(fake_status(name, i, float(t), stations[i], pid, kind), float(t))
            t1 = time.perf_counter()
            out = ctm.step(float(t))
            lat.append(time.perf_counter() - t1)
            ingest += t1 - t0
            for d in out:
                plans[d.drone] = (d.plan.plan_id, d.plan.kind.value)
        cpu = time.process_time() - cpu0
        lat.sort()
        rows.append(
            (
                cpu / seconds,
                statistics.median(lat),
                lat[int(0.99 * (len(lat) - 1))],
                ingest / seconds,
                ctm.decisions,
            )
        )
    cpu_s = statistics.median(r[0] for r in rows)
    med = statistics.median(r[1] for r in rows)
    p99 = statistics.median(r[2] for r in rows)
    ing = statistics.median(r[3] for r in rows)
    print(
        f"{'CPU s per sim s':>16} {'decision median':>16} {'decision p99':>13} "
        f"{'ingest only':>12} {'ratio':>6}"
    )
    print(
        f"{cpu_s:>16.4f} {1e3 * med:>13.2f} ms {1e3 * p99:>10.2f} ms {1e3 * ing:>9.2f} ms "
        f"{(med + ing) / ing:>6.2f}"
    )


def table_continuity(quick: bool) -> None:
    if quick:
        kw: dict[str, float] = {"duration_s": 300.0, "flight_time_s": 150.0, "swap_s": 20.0}
        fail = 120.0
    else:
        kw, fail = {"duration_s": 3600.0}, 1200.0
    print(
        f"\nhandoff continuity: 3 drones, {kw['duration_s']:.0f} s simulated, the patrolling "
        f"drone fails at {fail:.0f} s (one run each, lockstep: deterministic)"
    )
    print(
        f"{'relief joins':<22} {'coverage %':>10} {'max gap s':>9} {'handoffs':>8} "
        f"{'lap s':>6} {'handoff: median':>15} {'worst':>6} {'ratio':>6} "
        f"{'failure: revisit':>16} {'ratio':>6}"
    )
    for continuity, label in ((False, "nearest its station"), (True, "where the patrol is")):
        rep = PatrolExperiment(
            PatrolConfig(drones=3, fail_at_s=fail, continuity=continuity, **kw)  # type: ignore[arg-type]
        ).run()
        rows = [h for h in rep.handoff_revisit if h["straddle_max_s"] is not None]
        hs = [h for h in rows if h["kind"] == "handoff"]
        fs = [h for h in rows if h["kind"] == "replacement"]
        lap = statistics.median(h["baseline_s"] for h in rows if h["baseline_s"]) if rows else 0.0
        med = statistics.median(h["straddle_max_s"] for h in hs) if hs else math.nan
        worst = max((h["straddle_max_s"] for h in hs), default=math.nan)
        ratio = max((h["ratio"] for h in hs if h["ratio"] is not None), default=math.nan)
        f_s = max((h["straddle_max_s"] for h in fs), default=math.nan)
        f_r = max((h["ratio"] for h in fs if h["ratio"] is not None), default=math.nan)
        print(
            f"{label:<22} {100 * rep.coverage:>10.2f} {rep.max_gap_s:>9.1f} {rep.handoffs:>8} "
            f"{lap:>6.1f} {med:>15.1f} {worst:>6.1f} {ratio:>6.2f} {f_s:>16.1f} {f_r:>6.2f}"
        )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--seconds", type=float, default=None)
    ap.add_argument("--only", choices=("continuity",), default=None)
    a = ap.parse_args()
    repeats = a.repeats or (1 if a.quick else 3)
    seconds = a.seconds or (60.0 if a.quick else 300.0)
    if a.only is None:
        table_patrol(repeats, seconds)
        table_ctm(repeats, 60.0 if a.quick else 300.0)
    table_continuity(a.quick)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
