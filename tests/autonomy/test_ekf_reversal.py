"""Issue 13 §1: a climb reversed into a descent must never lock navdata out of the EKF.

In lockstep on the indoor world: take off, ``move up 1.5``, and while the drone climbs replace
the task with ``move down 0.5`` (exactly how the ANS ceiling monitor used to replace tasks).
Before the fix every navdata packet after the reversal was rejected by the joint outlier gate:
with the camera off the drone sank into the floor while the estimate climbed. Now the ultrasound
keeps the height, the drone settles 0.5 m below where it was, and the vertical error stays
consistent with the filter's own covariance (NEES)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drone.sim.world import load_world

from .flight import Flight

CHI2_1_999 = 10.83  # χ²(1) 99.9 % quantile


def _reverse(seed: int, camera: bool, climb_m_s: float) -> tuple[Flight, dict[str, float]]:
    f = Flight.make(load_world("indoor"), seed=seed, camera=camera)
    f.submit({"action": "takeoff"})
    assert f.run_until_idle(15.0)
    f.submit({"action": "move", "direction": "up", "distance": 1.5})
    sim, ekf = f.rig.sim, f.rig.vehicle.ekf
    assert f.rig.run_until(lambda: sim.truth.vz >= climb_m_s, 10.0)
    down = {"action": "move", "direction": "down", "distance": 0.5}
    decisions = f.tm.submit([down], replace=True)
    assert decisions[0].accepted, decisions
    target = f.rig.vehicle.setpoint.z - 0.5  # the hold point the replacement starts from
    low, worst, nees_z, disagree = math.inf, 0.0, [], 0
    end = f.rig.clock.now() + 8.0
    while f.rig.clock.now() < end:
        f.rig.step()
        tr, est = sim.truth, ekf.latest
        low = min(low, tr.z)
        disagree += bool(est.disagreement)
        if abs(est.t - tr.t_s) < 1e-6:  # a navdata instant: estimate and truth share a stamp
            worst = max(worst, abs(est.z - tr.z))
            nees_z.append((est.z - tr.z) ** 2 / est.P[2, 2])
    return f, {
        "target": target,
        "low": low,
        "worst": worst,
        "nees_z": float(np.mean(nees_z)),
        "disagree": disagree,
    }


@pytest.mark.parametrize("climb_m_s", [0.3, 0.5, 0.65])
def test_reversal_with_the_camera_off_keeps_the_height(climb_m_s: float) -> None:
    f, r = _reverse(seed=1, camera=False, climb_m_s=climb_m_s)
    ekf = f.rig.vehicle.ekf
    assert r["low"] > r["target"] - 0.1, r  # before: the drone sank to the floor (0.0 m)
    assert r["worst"] < 0.08, r  # before: the estimate climbed to 4 m while the drone sank
    assert abs(f.rig.sim.truth.z - r["target"]) < 0.1
    assert ekf.stats.navdata_rejected == 0 and ekf.stats.navdata_reinits == 0
    assert r["disagree"] == 0
    assert r["nees_z"] < CHI2_1_999, r
    assert "Moved down 0.5 m" in [e.text for e in f.events if e.kind == "done"]


@pytest.mark.timeout(300)
def test_reversal_with_markers_in_view_keeps_the_height() -> None:
    f, r = _reverse(seed=2, camera=True, climb_m_s=0.6)
    assert f.rig.vehicle.ekf.stats.fixes_accepted > 0  # the markers were in view
    assert r["low"] > r["target"] - 0.1, r  # before: it sank to ~0.5 m before fixes caught it
    assert r["worst"] < 0.08, r
    assert f.rig.vehicle.ekf.stats.navdata_reinits == 0
    assert r["nees_z"] < CHI2_1_999, r


def test_one_bad_component_does_not_drop_the_others() -> None:
    """A velocity glitch is gated on its own; the altitude of the same packet is still fused."""
    from drone.perception.ekf import ExtendedKalmanFilter, NavdataInput

    ekf, twin = ExtendedKalmanFilter(), ExtendedKalmanFilter()
    for f in (ekf, twin):
        f.reset(0.0, 1.0, 1.0, 1.0, 0.0)
        for k in range(1, 10):
            f.update_navdata(NavdataInput(k / 15, 0.0, 0.0, 0.0, 1.0, 0.0))
    before = ekf.latest.z
    assert not ekf.update_navdata(NavdataInput(10 / 15, 5.0, 0.0, 0.0, 1.05, 0.0))
    assert twin.update_navdata(NavdataInput(10 / 15, 0.0, 0.0, 0.0, 1.05, 0.0))
    assert ekf.stats.navdata_component_rejects == {"velocity": 1}
    assert ekf.latest.z > before + 0.005  # the altitude of the glitched packet went in…
    assert ekf.latest.z == pytest.approx(twin.latest.z, abs=1e-9)  # …exactly as without it
    assert ekf.latest.vx == pytest.approx(0.0, abs=0.05)  # the glitch did not


def test_persistent_rejection_reinitialises_from_navdata_and_reports_disagreement() -> None:
    """An over-confident, wrong height: after a few packets the estimate says it disagrees with
    the sensors, after ``nav_reinit_after`` it restarts from the ultrasound."""
    from drone.perception.ekf import EkfConfig, ExtendedKalmanFilter, NavdataInput

    cfg = EkfConfig()
    ekf = ExtendedKalmanFilter(cfg)
    ekf.reset(0.0, 1.0, 1.0, 3.0, 0.0, pos_sigma=0.01)  # believes 3 m, the drone is at 1 m
    seen = []
    for k in range(1, cfg.nav_reinit_after + 1):
        ekf.update_navdata(NavdataInput(k / 15, 0.0, 0.0, 0.0, 1.0, 0.0))
        seen.append(ekf.latest.disagreement)
    assert seen[cfg.disagree_after - 2] == ()
    assert seen[cfg.disagree_after - 1] == ("altitude",)
    assert seen[-1] == ()  # re-initialised on the last one
    assert ekf.stats.navdata_reinits == 1
    assert ekf.latest.z == pytest.approx(1.0, abs=0.01)
    assert ekf.latest.P[2, 2] == pytest.approx(cfg.alt_sigma**2)
