"""What the estimator's per-component gating and vertical noise cost and give, each against its
baseline (the joint-gate filter) in one run.

1. Cost of one navdata update: per-component gating (altitude and vertical speed as direct
   scalar updates, planar velocity as a 2-dof update) against the joint 4-dof gated update of
   the baseline (run here through the same filter's general update).
2. The climb reversal in lockstep (camera off): ``move up 1.5``, then ``move down 0.5`` replacing
   it at ~0.65 m/s: the lowest true height, the worst height error of the estimate and the
   navdata rejected — with the filter as it is, and with the baseline's settings (joint gate,
   σa,z 0.5 m/s², no re-initialisation from navdata).

    python bench/estimator.py [--quick] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from drone.lockstep import LockstepRig  # noqa: E402
from drone.perception import ekf as E  # noqa: E402
from drone.sim.world import load_world  # noqa: E402
from server.tasks import TaskManager  # noqa: E402


class JointGateEkf(E.ExtendedKalmanFilter):
    """The baseline filter: one joint χ²(4) gate on the whole navdata packet."""

    def _apply_navdata(self, nav: E.NavdataInput) -> bool:
        c = self.cfg
        self._predict(nav.t - self.t, nav.yaw_rate)
        self.t, self.omega = nav.t, nav.yaw_rate
        psi, vx, vy = self.x[E.IYAW], self.x[E.IVX], self.x[E.IVY]
        cs, sn = math.cos(psi), math.sin(psi)
        hx = np.array([cs * vx + sn * vy, -sn * vx + cs * vy, self.x[E.IVZ], self.x[E.IZ]])
        H = np.zeros((4, E.NX))
        H[0, E.IYAW], H[0, E.IVX], H[0, E.IVY] = -sn * vx + cs * vy, cs, sn
        H[1, E.IYAW], H[1, E.IVX], H[1, E.IVY] = -cs * vx - sn * vy, -sn, cs
        H[2, E.IVZ] = H[3, E.IZ] = 1.0
        z = np.array([nav.vx_body, nav.vy_body, nav.vz, nav.altitude_m])
        R = np.diag([c.vel_sigma**2, c.vel_sigma**2, c.vz_sigma**2, c.alt_sigma**2])
        ok, _ = self._update(z - hx, H, R, gate=True)
        if ok:
            self.stats.navdata_updates += 1
        else:
            self.stats.navdata_rejected += 1
        return ok


def update_cost_us(cls: type[E.ExtendedKalmanFilter], n: int) -> float:
    ekf = cls()
    ekf.reset(0.0, 1.0, 1.0, 1.0, 0.0)
    t0 = time.perf_counter()
    for k in range(1, n + 1):
        ekf.update_navdata(E.NavdataInput(k / 15, 0.1, 0.0, 0.0, 1.0, 0.0))
    return (time.perf_counter() - t0) / n * 1e6


def reversal(before: bool, seed: int) -> dict[str, float]:
    world = load_world("indoor")
    rig = LockstepRig(world, seed=seed, camera=False)
    if before:
        v = rig.vehicle
        cfg = E.EkfConfig(accel_sigma_z=0.5, nav_reinit_after=10**9)
        v.ekf = JointGateEkf(cfg, t0=rig.clock.now())
        t = rig.sim.truth
        v.ekf.reset(rig.clock.now(), t.x, t.y, t.z, t.yaw_rad)
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    assert rig.wait_link()
    tm.submit([{"action": "takeoff"}])
    rig.run_until(lambda: tm.current is None, 15.0)
    tm.submit([{"action": "move", "direction": "up", "distance": 1.5}])
    rig.run_until(lambda: rig.sim.truth.vz >= 0.65, 10.0)
    tm.submit([{"action": "move", "direction": "down", "distance": 0.5}], replace=True)
    low, worst = math.inf, 0.0
    for _ in range(round(6.0 / rig.dt)):
        rig.step()
        tr, est = rig.sim.truth, rig.vehicle.ekf.latest
        low, worst = min(low, tr.z), max(worst, abs(est.z - tr.z))
    return {
        "lowest_true_z_m": low,
        "worst_z_error_m": worst,
        "navdata_rejected": float(rig.vehicle.ekf.stats.navdata_rejected),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    ap.add_argument("--json", type=Path, help="write the results here too")
    args = ap.parse_args(argv)
    reps, n = (3, 1000) if args.quick else (9, 3000)
    now_us, before_us = [], []
    for _ in range(reps):  # interleaved, so load changes hit both alike
        now_us.append(update_cost_us(E.ExtendedKalmanFilter, n))
        before_us.append(update_cost_us(JointGateEkf, n))
    cost = {"now_us": statistics.median(now_us), "joint_us": statistics.median(before_us)}
    print(f"navdata update (median of {reps} × {n})")
    print("| update | µs | ratio |\n|---|---|---|")
    ratio = cost["now_us"] / cost["joint_us"]
    print(f"| per component (now) | {cost['now_us']:.1f} | {ratio:.2f} |")
    print(f"| joint χ²(4) gate (before) | {cost['joint_us']:.1f} | 1.00 |")
    rows = {"now": reversal(False, 0), "before": reversal(True, 0)}
    print("\nclimb reversal at 0.65 m/s, camera off (lockstep, seed 0; target 0.5 m below)")
    print("| filter | lowest true height | worst height error | navdata rejected |")
    print("|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['lowest_true_z_m']:.2f} m | {r['worst_z_error_m']:.2f} m "
            f"| {r['navdata_rejected']:.0f} |"
        )
    if args.json:
        args.json.write_text(json.dumps({"cost": cost, "reversal": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
