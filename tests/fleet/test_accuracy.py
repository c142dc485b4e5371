"""Issue 13 §13: the GPS arrival radius comes from the GPS noise (it was 1.0 m, below the
assumed σ of 1.5 m), and GPS patrol plans carry it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drone.sim.world import load_world
from server.fleet.accuracy import GPS_ARRIVAL_RADIUS_M, GPS_SIGMA_M, arrival_radius_m
from server.fleet.ctm import CentralTaskManager
from server.fleet.geo import Enu, origin_of
from server.fleet.messages import LtmStatus, PlanKind


def test_the_radius_is_the_gps_drms() -> None:
    """DRMS = √2·σ holds 1 − e⁻¹ ≈ 63 % of fixes; 2DRMS about 95–98 %; the old 1.0 m ~20 %."""
    assert pytest.approx(2.1) == GPS_ARRIVAL_RADIUS_M
    assert GPS_ARRIVAL_RADIUS_M > GPS_SIGMA_M
    rng = np.random.default_rng(13)
    errors = np.hypot(*rng.normal(0.0, GPS_SIGMA_M, (2, 200_000)))
    assert np.mean(errors <= math.sqrt(2) * GPS_SIGMA_M) == pytest.approx(0.632, abs=0.005)
    assert 0.95 < np.mean(errors <= 2 * math.sqrt(2) * GPS_SIGMA_M) < 0.985
    assert np.mean(errors <= 1.0) < 0.21  # the old radius: 4 fixes in 5 fell outside it
    assert arrival_radius_m(1.0, 0.95) == pytest.approx(math.sqrt(-2 * math.log(0.05)))
    for bad in ((0.0, 0.5), (float("nan"), 0.5), (1.5, 1.0), (1.5, 0.0)):
        with pytest.raises(ValueError):
            arrival_radius_m(*bad)


def _status(name: str, station: Enu) -> LtmStatus:
    return LtmStatus(
        name=name, t=0.0, seq=1, x=station.x, y=station.y, z=0.0, yaw_deg=0.0, lat=0.0,
        lon=0.0, battery_pct=100.0, flying=False, state="LANDED", link_ok=True,
        emergency=False, station=station, plan_id=0, task="", task_state="idle",
        progress=0.0, autonomous="",
    )  # fmt: skip


@pytest.mark.parametrize(("world_name", "radius"), [("outdoor", 2.1), ("indoor", 1.0)])
def test_patrol_plans_carry_the_radius_of_their_positioning(world_name: str, radius: float) -> None:
    world = load_world(world_name)
    ctm = CentralTaskManager(origin=origin_of(world), world=world)
    ctm.on_status(_status("uav1", Enu(*world.stations[0].position)), 0.0)
    z = 5.0 if world_name == "outdoor" else 1.5
    ctm.add_mission([Enu(-15.0 if z > 2 else 2.0, 2.0, z), Enu(3.0, 3.0, z)][:2], now=0.0)
    plans = [d.plan for d in ctm.step(1.0) if d.plan.kind is PlanKind.PATROL]
    assert plans and plans[0].tolerance_m == pytest.approx(radius)
