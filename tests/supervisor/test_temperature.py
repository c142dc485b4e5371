"""The temperature monitor: the simulator heats the hull with the motors' load (cooling on the
ground), the navdata carries the reading (tag 21), the supervisor warns, then lands."""

from __future__ import annotations

import math

import pytest

from drone.ardrone.navdata import TAG_PRESSURE_RAW, decode_navdata, encode_navdata
from drone.sim.drone import SimDrone
from drone.sim.errors import FaultError
from drone.sim.thermal import RISE_AT_HOVER_C, TAU_FLYING_S, Thermal, payload_factor
from drone.sim.world import load_world
from drone.supervisor import Phase
from drone.supervisor.temperature import TemperatureMonitor
from server.settings import Settings, SettingsError
from tests.dialog.lockstep_dialog import dialog_rig
from tests.supervisor.snaps import cmd, snap


def test_the_hull_settles_at_its_rise_with_the_square_of_the_load_and_cools_landed() -> None:
    th = Thermal()
    for _ in range(round(10 * TAU_FLYING_S)):
        th.step(1.0, 1.0, True)
    assert th.rise_c == pytest.approx(RISE_AT_HOVER_C, abs=0.01)  # hover
    after_one_tau = Thermal()
    for _ in range(round(TAU_FLYING_S)):
        after_one_tau.step(1.0, 1.5, True)  # full climb: 1.5² of the hover rise
    assert after_one_tau.rise_c == pytest.approx(
        RISE_AT_HOVER_C * 2.25 * (1 - math.exp(-1)), rel=1e-3
    )
    landed = th.rise_c
    th.step(60.0, 1.0, False)  # motors off: cools, more slowly than it heated
    assert 0.0 < th.rise_c < landed
    assert th.rise_c > landed * math.exp(-60.0 / TAU_FLYING_S)
    assert payload_factor(0.0) == 1.0 and payload_factor(0.15) == pytest.approx(1.581, abs=1e-3)


def test_the_navdata_carries_the_heated_reading_where_the_sdk_puts_it() -> None:
    sim = SimDrone(load_world("indoor"), seed=3)
    sim.thermal.rise_c = 30.0
    sim._navdata_options = 1 << TAG_PRESSURE_RAW  # as the vehicle asks (drone/ardrone/vehicle.py)
    sim._demo = True  # past the bootstrap handshake
    nav = decode_navdata(encode_navdata(sim.navdata()))
    assert nav.pressure is not None
    assert nav.pressure.temperature_c == pytest.approx(51.0, abs=0.5)  # 21 °C room + 30
    assert sim.truth.temperature_c == pytest.approx(51.0)


def test_a_payload_is_checked() -> None:
    sim = SimDrone(load_world("indoor"), seed=3)
    for bad in (-0.1, 0.3, math.nan):
        with pytest.raises(FaultError, match="payload"):
            sim.inject_fault("payload", kg=bad)
    with pytest.raises(SettingsError, match="temperature_warn_c"):
        Settings().with_(temperature_warn_c=70.0)


def test_the_monitor_warns_then_lands_once_each_and_re_arms_when_cool() -> None:
    m = TemperatureMonitor(55.0, 60.0)
    assert m.check(snap(temperature_c=None), Phase.EXECUTING, 0.0) is None
    assert m.check(snap(temperature_c=50.0), Phase.EXECUTING, 1.0) is None
    warn = m.check(snap(temperature_c=55.2), Phase.EXECUTING, 2.0)
    assert warn is not None and warn.severity == "warn" and warn.action is None
    assert "land at 60" in warn.text
    assert m.check(snap(temperature_c=57.0), Phase.EXECUTING, 3.0) is None  # latched
    land = m.check(snap(temperature_c=60.1), Phase.EXECUTING, 4.0)
    assert land is not None and land.severity == "alert" and cmd(land) == {"action": "land"}
    assert "limit of its battery" in land.text
    assert m.check(snap(temperature_c=61.0, flying=False), Phase.GROUNDED, 5.0) is None
    assert m.check(snap(temperature_c=52.0, flying=False), Phase.GROUNDED, 6.0) is None
    hot = m.check(snap(temperature_c=60.5, flying=False), Phase.GROUNDED, 7.0)
    assert hot is not None and hot.action is None and "cool before flying" in hot.text


def test_a_long_heavy_flight_warns_then_lands_and_says_why() -> None:
    """150 g on board (≈1.58× the hover current): the hull climbs towards 21 + 62 °C; the
    supervisor warns at 55 °C and lands at 60 °C, the dialog says both, the audit log has both."""
    r = dialog_rig(seed=4)
    r.rig.sim.inject_fault("payload", kg=0.15)
    assert r.rig.takeoff_all()
    r.tm.submit([{"action": "hover"}])
    assert r.rig.run_until(lambda: not r.rig.sim.truth.flying, 400.0)
    texts = [(x["level"], x["text"]) for x in r.replies if x.get("alarm") == "temperature"]
    assert [lv for lv, _ in texts] == ["warn", "alert"], texts
    assert "I will land at 60" in texts[0][1] and "Landing now" in texts[1][1]
    t_land = r.rig.sim.truth.temperature_c
    assert 59.0 <= t_land <= 63.0  # landed at the limit, not long after
    rows = [e for e in reversed(r.audit.recent(200)) if e.action == "ans:temperature"]
    assert [e.commands for e in rows] == [[], [{"action": "land"}]]
    assert [e.source for e in rows] == ["ans", "ans"]
    r.rig.run(1.0)
    assert r.dm.state.value == "LANDED"
