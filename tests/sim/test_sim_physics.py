"""Physics and battery in the AR.Drone's own terms, stepped directly (no wire)."""

from __future__ import annotations

import math

import pytest

from drone.ardrone.navdata import CtrlState
from drone.sim.battery import MAX_SAG_PCT_AT_HOVER, Battery
from drone.sim.errors import SimConfigError
from drone.sim.physics import Body, FlightParams, Physics, as_box

ROOM = (0.0, 8.0, 0.0, 6.0, 0.0, 3.0)
DT = 0.01


def run(ph: Physics, seconds: float) -> None:
    for _ in range(round(seconds / DT)):
        ph.step(DT)


def flying(yaw: float = 0.0, x: float = 4.0, y: float = 3.0) -> Physics:
    ph = Physics(bounds=ROOM, body=Body(x=x, y=y, yaw_rad=yaw))
    assert ph.takeoff()
    run(ph, 5.0)
    assert ph.ctrl is CtrlState.HOVERING
    return ph


def test_takeoff_climbs_to_about_0_8_m_then_hovers() -> None:
    ph = Physics(bounds=ROOM, body=Body(x=4, y=3))
    assert ph.takeoff()
    assert ph.ctrl is CtrlState.TAKEOFF
    run(ph, 5.0)
    assert ph.ctrl is CtrlState.HOVERING
    assert ph.body.z == pytest.approx(0.8, abs=0.05)
    assert (ph.body.x, ph.body.y) == pytest.approx((4.0, 3.0), abs=1e-6)


@pytest.mark.parametrize(
    ("yaw", "cmd", "direction"),
    [
        (0.0, (0.0, -1.0), (1.0, 0.0)),  # pitch < 0: forward along the heading
        (0.0, (0.0, 1.0), (-1.0, 0.0)),  # pitch > 0: backward
        (0.0, (-1.0, 0.0), (0.0, 1.0)),  # roll < 0: left (+y in FLU)
        (0.0, (1.0, 0.0), (0.0, -1.0)),  # roll > 0: right
        (math.pi / 2, (0.0, -1.0), (0.0, 1.0)),  # facing +y, forward is +y
    ],
)
def test_tilt_moves_the_drone_the_right_way(
    yaw: float, cmd: tuple[float, float], direction: tuple[float, float]
) -> None:
    ph = flying(yaw)
    x0, y0 = ph.body.x, ph.body.y
    ph.command(cmd[0], cmd[1], 0.0, 0.0, progressive=True)
    run(ph, 1.0)
    assert ph.ctrl is CtrlState.FLYING
    dx, dy = ph.body.x - x0, ph.body.y - y0
    assert dx * direction[0] + dy * direction[1] > 0.3
    assert abs(dx * direction[1] - dy * direction[0]) < 0.02  # no sideways drift


def test_top_speed_is_g_tan_tilt_over_drag_and_attitude_lags() -> None:
    ph = Physics(bounds=(0, 100, 0, 6, 0, 3), body=Body(x=1.0, y=3.0))
    ph.takeoff()
    run(ph, 5.0)
    p = ph.params
    ph.command(0.0, -1.0, 0.0, 0.0, progressive=True)
    ph.step(DT)
    assert 0 < ph.body.pitch_rad < p.euler_angle_max_rad * 0.2  # first-order lag, not a jump
    run(ph, 2.0)
    assert ph.body.pitch_rad == pytest.approx(p.euler_angle_max_rad, rel=1e-3)
    run(ph, 6.0)  # drag time constant 1/0.9 s: settled
    expected = 9.81 * math.tan(p.euler_angle_max_rad) / p.drag_per_s
    assert ph.body.vx == pytest.approx(expected, rel=0.01)
    assert ph.collisions == 0


def test_gaz_and_yaw_rates_and_the_ceiling() -> None:
    ph = flying()
    ph.command(0.0, 0.0, 1.0, 0.0, progressive=True)
    run(ph, 1.5)
    assert ph.body.vz == pytest.approx(0.7, rel=0.02)  # control_vz_max 700 mm/s
    run(ph, 5.0)
    assert ph.body.z <= ROOM[5] - ph.params.height_m + 1e-9  # room ceiling
    ph2 = Physics(bounds=(0, 8, 0, 6, 0, 10), body=Body(x=4, y=3), params=FlightParams())
    ph2.takeoff()
    run(ph2, 5)
    ph2.command(0, 0, 1, 0, True)
    run(ph2, 8)
    assert ph2.body.z == pytest.approx(3.0, abs=0.01)  # altitude_max 3 m
    ph.command(0.0, 0.0, 0.0, 0.5, progressive=True)
    yaw0 = ph.body.yaw_rad
    run(ph, 1.0)
    # yaw > 0 is clockwise: yaw (CCW positive) decreases at about 50 °/s after the lag
    turned = math.degrees(math.remainder(ph.body.yaw_rad - yaw0, math.tau))
    assert -50.0 < turned < -40.0


def test_hover_brakes_to_a_stop() -> None:
    ph = flying(x=2.0)
    ph.command(0.0, -1.0, 0.0, 0.0, progressive=True)
    run(ph, 1.0)
    ph.hover()
    run(ph, 4.0)
    assert math.hypot(ph.body.vx, ph.body.vy) < 0.02
    assert ph.ctrl is CtrlState.HOVERING


def test_walls_stop_the_drone() -> None:
    ph = flying(x=6.0)
    ph.command(0.0, -1.0, 0.0, 0.0, progressive=True)
    run(ph, 5.0)
    assert ph.body.x == pytest.approx(8.0 - ph.params.radius_m)
    assert ph.collisions > 0


def test_land_and_emergency_fall() -> None:
    ph = flying()
    ph.land()
    assert ph.ctrl is CtrlState.LANDING
    run(ph, 3.0)
    assert ph.ctrl is CtrlState.LANDED and ph.body.z == 0.0 and not ph.motors_on
    ph = flying()
    ph.cut_motors()
    assert ph.emergency and not ph.motors_on
    run(ph, 0.2)
    assert ph.body.vz < -1.0  # falling freely
    run(ph, 1.0)
    assert ph.body.z == 0.0 and ph.emergency
    assert not ph.takeoff()  # refused in emergency
    ph.reset_emergency()
    assert ph.ctrl is CtrlState.LANDED and ph.takeoff()


def test_wind_pushes_a_hovering_drone_and_gusts_expire() -> None:
    ph = flying()
    ph.gust(3.0, 0.0, 2.0)
    run(ph, 2.0)
    assert ph.body.x > 4.3
    assert ph.air() == (3.0, 0.0)
    run(ph, 0.1)
    assert ph.air() == (0.0, 0.0)


def test_battery_twelve_minutes_climb_costs_more_low_refuses_takeoff() -> None:
    b = Battery()
    for _ in range(720):
        b.step(1.0, motors_on=True)
    assert b.pct == pytest.approx(0.0, abs=1e-6)
    hover, climb = Battery(), Battery()
    hover.step(60, True, 0.0)
    climb.step(60, True, 1.0)
    assert 100 - climb.pct == pytest.approx(1.5 * (100 - hover.pct))
    idle = Battery()
    idle.step(60, False)
    assert idle.pct > 99.5
    ph = Physics(bounds=ROOM, battery=Battery(pct=19.0))
    assert ph.battery.low and not ph.takeoff()
    ph = flying()
    ph.battery.drain_to(0.0)
    run(ph, 0.05)
    assert ph.ctrl is CtrlState.LANDING  # the firmware lands on an empty battery


def test_a_worn_pack_reads_lower_under_load_and_recovers_when_it_falls() -> None:
    healthy = Battery(pct=50.0)
    healthy.step(0.01, True, 1.0)
    assert healthy.reading_pct == pytest.approx(healthy.pct)  # the paper's model: no sag
    worn = Battery(pct=30.0)
    worn.wear(10.0)
    worn.step(0.01, False)
    assert worn.reading_pct == pytest.approx(worn.pct)  # motors off: no current, no sag
    worn.step(0.01, True, 0.0)
    assert worn.pct - worn.reading_pct == pytest.approx(10.0)  # hover
    worn.step(0.01, True, 1.0)
    assert worn.pct - worn.reading_pct == pytest.approx(15.0)  # full climb: 1.5 x the current
    worn.step(0.01, True, 0.0)
    assert worn.pct - worn.reading_pct == pytest.approx(10.0)  # back at hover: recovered
    worn.wear(99.0)
    assert worn.sag_pct_at_hover == MAX_SAG_PCT_AT_HOVER  # the most the model allows


@pytest.mark.parametrize(
    "bad", [(0, 1, 2), (0, 0, 0, 1, 0, 1), (0, 1, 0, 1, 0, float("nan")), "abcdef", None]
)
def test_bad_bounds_raise(bad: object) -> None:
    with pytest.raises(SimConfigError):
        as_box(bad)
