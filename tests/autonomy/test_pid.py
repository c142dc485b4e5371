"""The paper's controller (eq. 1): signs, scales, clamping, anti-windup, and why the damping
sign had to be fixed."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drone.control.errors import GainError
from drone.control.pid import DroneLimits, PaperGains, PaperPID, Setpoint, wrap_angle


@dataclass(frozen=True)
class S:
    x: float = 0.0
    y: float = 0.0
    z: float = 1.0
    yaw_rad: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0


def test_target_ahead_pitches_nose_down_by_the_paper_scale_converted_to_the_drone_limit() -> None:
    pid = PaperPID()
    out = pid.paper_output(S(), Setpoint(0.5, 0.0, 1.0, 0.0), 0.01)
    assert out.forward == pytest.approx(0.25)  # 0.5 · 0.5 m
    cmd = pid.to_pcmd(out)
    # 0.25 of 18° = 4.5°, which is 0.375 of the drone's 12°; forward = pitch < 0 (SDK §6.6)
    assert cmd.pitch == pytest.approx(-0.375)
    assert cmd.roll == pytest.approx(0.0)
    assert cmd.gaz == pytest.approx(0.0)
    assert cmd.yaw == pytest.approx(0.0)


def test_planar_error_is_rotated_into_the_body_frame() -> None:
    pid = PaperPID()
    # facing +y (yaw 90°): a target at +y is straight ahead, one at +x is to the right
    ahead = pid.step(S(yaw_rad=math.pi / 2), Setpoint(0.0, 0.4, 1.0, math.pi / 2), 0.01)
    assert ahead.pitch < -0.1 and abs(ahead.roll) < 1e-9
    right = pid.step(S(yaw_rad=math.pi / 2), Setpoint(0.4, 0.0, 1.0, math.pi / 2), 0.01)
    assert right.roll > 0.1 and abs(right.pitch) < 1e-9  # roll > 0 = right


def test_yaw_rate_is_0_02_per_degree_and_clockwise_positive_on_the_wire() -> None:
    pid = PaperPID()
    out = pid.paper_output(S(), Setpoint(0, 0, 1.0, math.radians(10.0)), 0.01)
    assert out.yaw_rate == pytest.approx(0.2)  # 10° · 0.02
    cmd = pid.to_pcmd(out)
    assert cmd.yaw == pytest.approx(-0.2 * 90.0 / 100.0)  # CCW target → PCMD yaw < 0
    # the error is wrapped: 350° away is −10°
    out2 = pid.paper_output(S(yaw_rad=math.radians(175)), Setpoint(0, 0, 1, math.radians(-175)), 0)
    assert out2.yaw_rate == pytest.approx(0.2)


def test_vertical_law_and_its_conversion() -> None:
    pid = PaperPID()
    out = pid.paper_output(S(z=1.0, vz=0.5), Setpoint(0, 0, 1.5, 0.0), 0.0)
    assert out.climb == pytest.approx(0.6 * 0.5 - 0.2 * 0.5)
    assert pid.to_pcmd(out).gaz == pytest.approx(out.climb * 2.0 / 0.7)


def test_damping_opposes_velocity() -> None:
    pid = PaperPID()
    moving = pid.paper_output(S(vx=1.0, vz=1.0), Setpoint(0, 0, 1.0, 0), 0.0)
    assert moving.forward == pytest.approx(-0.32)
    assert moving.climb == pytest.approx(-0.2)


def test_planar_saturation_keeps_the_direction() -> None:
    cmd = PaperPID().step(S(), Setpoint(30.0, 30.0, 1.0, 0.0), 0.01)
    assert math.hypot(cmd.roll, cmd.pitch) == pytest.approx(1.0)
    assert cmd.pitch == pytest.approx(-math.sqrt(0.5))  # forward and left equally
    assert cmd.roll == pytest.approx(-math.sqrt(0.5))


def test_anti_windup_freezes_the_integral_while_saturated() -> None:
    pid = PaperPID()
    for _ in range(1000):  # 10 s with a 5 m height error: output saturated upwards
        pid.step(S(z=0.0), Setpoint(0, 0, 5.0, 0), 0.01)
    assert pid.integral_z == pytest.approx(0.0)
    for _ in range(20000):  # small error, not saturated: integrates up to its cap
        pid.step(S(z=0.9), Setpoint(0, 0, 1.0, 0), 0.01)
    cap = PaperGains().i_max_frac / PaperGains().ki_z
    assert pid.integral_z == pytest.approx(cap)
    pid.reset()
    assert pid.integral_z == 0.0


@given(
    st.tuples(*[st.floats(-1e6, 1e6)] * 7),
    st.tuples(*[st.floats(-1e6, 1e6)] * 4),
    st.floats(0, 10),
)
def test_outputs_are_always_fractions(
    state: tuple[float, ...], sp: tuple[float, ...], dt: float
) -> None:
    cmd = PaperPID().step(S(*state), Setpoint(*sp), dt)
    for v in (cmd.roll, cmd.pitch, cmd.gaz, cmd.yaw):
        assert -1.0 <= v <= 1.0 and math.isfinite(v)


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(GainError):
        PaperGains(kp_xy=-1.0)
    with pytest.raises(GainError):
        PaperGains(tilt_scale_deg=0.0)
    with pytest.raises(GainError):
        DroneLimits(euler_angle_max_deg=float("nan"))
    with pytest.raises(ValueError):
        PaperPID().step(S(), Setpoint(0, 0, 1, 0), -0.01)
    with pytest.raises(ValueError):
        Setpoint(float("inf"), 0, 1, 0)


def _simulate(kd_sign: float, seconds: float = 20.0) -> float:
    """1-D: attitude lag 0.15 s, a = g·tan(tilt) − 0.9·v (the simulator's model). Max |x| late."""
    pid, dt = PaperPID(), 0.01
    x, v, tilt = 1.0, 0.0, 0.0
    worst = 0.0
    for k in range(int(seconds / dt)):
        # eq. 1 as printed (+) or fixed (−): u = 0.5·e ± 0.32·v
        u = 0.5 * (0.0 - x) + kd_sign * 0.32 * v
        target = max(-1.0, min(1.0, u)) * math.radians(18.0)
        target = max(
            -pid.limits.euler_angle_max_deg,
            min(pid.limits.euler_angle_max_deg, math.degrees(target)),
        )
        tilt += (math.radians(target) - tilt) * dt / 0.15
        v += (9.81 * math.tan(tilt) - 0.9 * v) * dt
        x += v * dt
        if k * dt > seconds - 5.0:
            worst = max(worst, abs(x))
    return worst


def test_the_printed_damping_sign_is_worse_and_the_fixed_one_settles() -> None:
    fixed = _simulate(-1.0)
    printed = _simulate(+1.0)
    assert fixed < 0.02  # settled within 2 cm after 15 s
    assert printed > 10 * fixed  # the printed "+0.32·v" does not settle


def test_wrap_angle() -> None:
    assert wrap_angle(3 * math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(-0.1) == pytest.approx(-0.1)
