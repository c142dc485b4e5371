"""AR.Drone 2.0 flight physics in the drone's own terms (what its onboard controller exposes).

The AR.Drone flies on an onboard controller: AT*PCMD asks for a tilt (fraction of
``euler_angle_max``), a vertical speed (fraction of ``control_vz_max``) and a yaw rate (fraction
of ``control_yaw``) (Developer Guide SDK 2.0 §6.6, defaults from ARDroneLib ``config_keys.h``).
This module models that closed loop, not the rotors:

* attitude tracks the commanded tilt with a first-order lag (``attitude_tau_s``);
* tilt gives horizontal acceleration ``g·tan(tilt)`` against linear drag on the air-relative
  velocity (``drag_per_s``), so wind pushes the drone;
* vertical speed and yaw rate track their targets with first-order lags;
* hover (PCMD flag 0, or no command) brakes to zero ground speed as the drone does with its
  optical flow, and holds altitude;
* take-off climbs to ``takeoff_altitude_m`` (~0.8 m), landing descends to the floor, the ceiling
  is ``altitude_max`` above the floor, walls/floor/ceiling of the world box stop the drone;
* EMERGENCY cuts the motors: the drone falls and lies on the floor until reset.

Frames (docs/CONVENTIONS.md): map frame x, y, z up; yaw CCW positive. Attitude is kept in
REP 103 too: ``roll_rad`` positive = right wing down, ``pitch_rad`` positive = nose down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from drone.ardrone.navdata import CtrlState
from drone.sim.battery import Battery
from drone.sim.errors import SimConfigError

G = 9.81  # m/s²


@dataclass(frozen=True)
class FlightParams:
    """Onboard-controller limits (config keys) and model constants."""

    euler_angle_max_rad: float = math.radians(12.0)  # control:euler_angle_max, indoor default
    control_vz_max_m_s: float = 0.7  # control:control_vz_max 700 mm/s
    control_yaw_rad_s: float = math.radians(100.0)  # control:control_yaw 100 °/s
    altitude_max_m: float = 3.0  # control:altitude_max 3000 mm
    takeoff_altitude_m: float = 0.8  # AR.Drone 2.0 hovers about 0.8 m after take-off
    spinup_s: float = 0.6  # motors start before the climb
    takeoff_climb_m_s: float = 0.5
    landing_descent_m_s: float = 0.5
    attitude_tau_s: float = 0.15  # first-order lag of the attitude loop
    vz_tau_s: float = 0.25
    yaw_tau_s: float = 0.1
    drag_per_s: float = 0.9  # linear drag: top speed g·tan(12°)/0.9 ≈ 2.3 m/s
    hover_brake_rad_per_m_s: float = 0.12  # tilt per m/s of ground speed while hovering
    radius_m: float = 0.26  # indoor hull half-width (51.7 cm across)
    height_m: float = 0.12


Box = tuple[float, float, float, float, float, float]  # x_min, x_max, y_min, y_max, z_min, z_max


def as_box(bounds: Any) -> Box:
    """Accept ``drone.sim.world.Bounds`` (attributes ``x_min``…``z_max``) or a 6-tuple.

    Raises:
        SimConfigError: not six finite numbers with min < max on each axis.
    """
    if hasattr(bounds, "x_min"):
        keys = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
        vals = tuple(float(getattr(bounds, k)) for k in keys)
    else:
        try:
            vals = tuple(float(v) for v in bounds)
        except (TypeError, ValueError) as exc:
            raise SimConfigError(f"bounds must be 6 numbers, got {bounds!r}") from exc
    if len(vals) != 6 or not all(math.isfinite(v) for v in vals):
        raise SimConfigError(f"bounds must be 6 finite numbers, got {bounds!r}")
    if not (vals[0] < vals[1] and vals[2] < vals[3] and vals[4] < vals[5]):
        raise SimConfigError(f"bounds need min < max on each axis, got {vals}")
    return vals  # type: ignore[return-value,unused-ignore]


def _lag(value: float, target: float, dt: float, tau: float) -> float:
    return target + (value - target) * math.exp(-dt / tau) if tau > 0 else target


def _clip(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


@dataclass
class Body:
    """True rigid-body state in the map frame (mutable, owned by :class:`Physics`)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    yaw_rad: float = 0.0
    yaw_rate: float = 0.0
    roll_rad: float = 0.0  # right wing down positive
    pitch_rad: float = 0.0  # nose down positive (REP 103)

    def body_velocity(self) -> tuple[float, float]:
        """(forward, left) ground velocity in the body frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return c * self.vx + s * self.vy, -s * self.vx + c * self.vy


@dataclass
class Physics:
    """The drone's dynamics plus its control state machine. ``step(dt)`` advances time."""

    bounds: Box
    params: FlightParams = field(default_factory=FlightParams)
    battery: Battery = field(default_factory=Battery)
    body: Body = field(default_factory=Body)
    ctrl: CtrlState = CtrlState.LANDED
    emergency: bool = False
    wind: tuple[float, float] = (0.0, 0.0)  # steady wind, m/s in the map frame
    t: float = 0.0
    # commanded inputs (AT*PCMD)
    cmd_roll: float = 0.0
    cmd_pitch: float = 0.0
    cmd_gaz: float = 0.0
    cmd_yaw: float = 0.0
    cmd_progressive: bool = False
    _gusts: list[tuple[float, float, float]] = field(default_factory=list)  # (vx, vy, until_t)
    _phase_t: float = 0.0  # time in the current TAKEOFF phase
    collisions: int = 0

    def __post_init__(self) -> None:
        self.bounds = as_box(self.bounds)
        b = self.body
        x0, x1, y0, y1, z0, _ = self.bounds
        r = self.params.radius_m
        b.x, b.y = _clip(b.x, x0 + r, x1 - r), _clip(b.y, y0 + r, y1 - r)
        b.z = max(b.z, z0)

    # ------------------------------------------------------------ commands
    def command(self, roll: float, pitch: float, gaz: float, yaw: float, progressive: bool) -> None:
        """Latest AT*PCMD; values clipped to [-1, 1]; NaN is treated as 0 (the drone ignores it)."""

        def f(v: float) -> float:
            return _clip(v, -1.0, 1.0) if math.isfinite(v) else 0.0

        self.cmd_roll, self.cmd_pitch = f(roll), f(pitch)
        self.cmd_gaz, self.cmd_yaw = f(gaz), f(yaw)
        self.cmd_progressive = progressive

    def hover(self) -> None:
        self.command(0.0, 0.0, 0.0, 0.0, False)

    def takeoff(self) -> bool:
        """Start a take-off from LANDED. Refused (False) in emergency or with a low battery."""
        if self.ctrl is not CtrlState.LANDED or self.emergency or not self.battery.can_take_off:
            return False
        self.ctrl = CtrlState.TAKEOFF
        self._phase_t = 0.0
        self.hover()
        return True

    def land(self) -> None:
        """Descend to the floor (from TAKEOFF, HOVERING or FLYING)."""
        if self.ctrl in (CtrlState.TAKEOFF, CtrlState.HOVERING, CtrlState.FLYING):
            self.ctrl = CtrlState.LANDING

    def cut_motors(self) -> None:
        """EMERGENCY: motors off; the drone falls."""
        self.emergency = True
        self.ctrl = CtrlState.DEFAULT

    def reset_emergency(self) -> None:
        """Leave EMERGENCY (only once on the floor, as the real drone needs to be upright)."""
        if self.emergency and self.on_floor:
            self.emergency = False
            self.ctrl = CtrlState.LANDED
            b = self.body
            b.vx = b.vy = b.vz = b.yaw_rate = b.roll_rad = b.pitch_rad = 0.0

    def gust(self, vx: float, vy: float, duration_s: float) -> None:
        """Add a wind gust (m/s, map frame) for ``duration_s`` seconds."""
        self._gusts.append((vx, vy, self.t + duration_s))

    def clear_gusts(self) -> None:
        self._gusts.clear()

    # ------------------------------------------------------------ queries
    @property
    def motors_on(self) -> bool:
        return not self.emergency and self.ctrl in (
            CtrlState.TAKEOFF,
            CtrlState.HOVERING,
            CtrlState.FLYING,
            CtrlState.LANDING,
        )

    @property
    def flying(self) -> bool:
        return self.motors_on

    @property
    def on_floor(self) -> bool:
        return self.body.z <= self.bounds[4] + 1e-6

    @property
    def altitude_m(self) -> float:
        """Height above the floor (what the ultrasound measures)."""
        return self.body.z - self.bounds[4]

    def air(self) -> tuple[float, float]:
        """Current wind (steady + active gusts), m/s map frame."""
        wx, wy = self.wind
        for gx, gy, until in self._gusts:
            if self.t < until:
                wx, wy = wx + gx, wy + gy
        return wx, wy

    # ------------------------------------------------------------ dynamics
    def step(self, dt: float) -> None:
        """Advance ``dt`` seconds (semi-implicit Euler; stable for dt ≤ 0.05 s)."""
        if dt <= 0:
            return
        p, b = self.params, self.body
        self.t += dt
        self._gusts = [g for g in self._gusts if g[2] > self.t]
        if self.motors_on and self.battery.empty:
            self.land()  # the firmware lands on an empty battery
        floor = self.bounds[4]

        if self.emergency:
            self._fall(dt)
        elif self.ctrl is CtrlState.LANDED:
            b.x, b.y, b.z = b.x, b.y, floor
            b.vx = b.vy = b.vz = b.yaw_rate = b.roll_rad = b.pitch_rad = 0.0
        else:
            self._fly(dt)
        self._collide()
        climb = b.vz / p.control_vz_max_m_s if self.motors_on else 0.0
        self.battery.step(dt, self.motors_on, climb)

    def _fly(self, dt: float) -> None:
        p, b = self.params, self.body
        floor = self.bounds[4]
        fwd, left = b.body_velocity()
        tilt_max = p.euler_angle_max_rad
        manual = self.ctrl in (CtrlState.HOVERING, CtrlState.FLYING) and self.cmd_progressive
        if manual:
            # PCMD: roll > 0 right wing down (→ right), pitch < 0 nose down (→ forward).
            roll_t = self.cmd_roll * tilt_max
            pitch_t = -self.cmd_pitch * tilt_max  # REP 103 pitch: nose down positive
            vz_t = self.cmd_gaz * p.control_vz_max_m_s
            yaw_rate_t = -self.cmd_yaw * p.control_yaw_rad_s  # yaw > 0 is clockwise
            self.ctrl = CtrlState.FLYING
        else:
            # Hover: brake ground speed (optical flow), hold altitude.
            k = p.hover_brake_rad_per_m_s
            pitch_t = -_clip(k * fwd, -tilt_max, tilt_max)  # moving forward -> nose up
            roll_t = _clip(k * left, -tilt_max, tilt_max)  # moving left -> right wing down
            vz_t = 0.0
            yaw_rate_t = 0.0
            if self.ctrl is CtrlState.FLYING:
                self.ctrl = CtrlState.HOVERING
        if self.ctrl is CtrlState.TAKEOFF:
            self._phase_t += dt
            # Climb, slowing down near the target (P on altitude error), and report HOVERING only
            # once settled there, as the drone does at the end of its take-off sequence.
            error = p.takeoff_altitude_m - self.altitude_m
            vz_t = min(p.takeoff_climb_m_s, 2.0 * error) if self._phase_t >= p.spinup_s else 0.0
            if self._phase_t >= p.spinup_s and abs(error) < 0.01 and abs(b.vz) < 0.02:
                self.ctrl = CtrlState.HOVERING
                vz_t = 0.0
        elif self.ctrl is CtrlState.LANDING:
            vz_t = -p.landing_descent_m_s
        # Ceiling: control:altitude_max above the floor, and the room's ceiling.
        ceiling = min(floor + p.altitude_max_m, self.bounds[5] - p.height_m)
        if b.z >= ceiling and vz_t > 0:
            vz_t = 0.0
        b.roll_rad = _lag(b.roll_rad, roll_t, dt, p.attitude_tau_s)
        b.pitch_rad = _lag(b.pitch_rad, pitch_t, dt, p.attitude_tau_s)
        b.yaw_rate = _lag(b.yaw_rate, yaw_rate_t, dt, p.yaw_tau_s)
        b.vz = _lag(b.vz, vz_t, dt, p.vz_tau_s)
        # Tilt -> body acceleration: nose down (pitch > 0) pushes forward; right wing down pushes
        # right (−y in FLU).
        a_fwd = G * math.tan(b.pitch_rad)
        a_left = -G * math.tan(b.roll_rad)
        c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
        wx, wy = self.air()
        ax = c * a_fwd - s * a_left - p.drag_per_s * (b.vx - wx)
        ay = s * a_fwd + c * a_left - p.drag_per_s * (b.vy - wy)
        b.vx += ax * dt
        b.vy += ay * dt
        b.x += b.vx * dt
        b.y += b.vy * dt
        b.z += b.vz * dt
        if b.z > ceiling:
            b.z = max(ceiling, floor)
            b.vz = min(b.vz, 0.0)
        b.yaw_rad = math.remainder(b.yaw_rad + b.yaw_rate * dt, math.tau)
        if self.ctrl is CtrlState.LANDING and b.z <= floor + 1e-3:
            self.ctrl = CtrlState.LANDED
            b.z = floor
            b.vx = b.vy = b.vz = b.yaw_rate = b.roll_rad = b.pitch_rad = 0.0

    def _fall(self, dt: float) -> None:
        p, b = self.params, self.body
        floor = self.bounds[4]
        if b.z <= floor + 1e-6 and b.vz <= 0:
            b.z = floor
            b.vx = b.vy = b.vz = b.yaw_rate = 0.0
            b.roll_rad = b.pitch_rad = 0.0
            return
        wx, wy = self.air()
        b.vx -= p.drag_per_s * (b.vx - wx) * dt
        b.vy -= p.drag_per_s * (b.vy - wy) * dt
        b.vz -= G * dt
        b.x += b.vx * dt
        b.y += b.vy * dt
        b.z += b.vz * dt
        b.yaw_rad = math.remainder(b.yaw_rad + b.yaw_rate * dt, math.tau)

    def _collide(self) -> None:
        """Walls, floor and ceiling of the world box stop the drone (velocity into them zeroed)."""
        b, r = self.body, self.params.radius_m
        x0, x1, y0, y1, z0, z1 = self.bounds
        hit = False
        if b.x < x0 + r:
            b.x, b.vx, hit = x0 + r, max(b.vx, 0.0), True
        elif b.x > x1 - r:
            b.x, b.vx, hit = x1 - r, min(b.vx, 0.0), True
        if b.y < y0 + r:
            b.y, b.vy, hit = y0 + r, max(b.vy, 0.0), True
        elif b.y > y1 - r:
            b.y, b.vy, hit = y1 - r, min(b.vy, 0.0), True
        if b.z < z0:
            b.z, b.vz = z0, max(b.vz, 0.0)
        elif b.z > z1 - self.params.height_m:
            b.z, b.vz, hit = max(z1 - self.params.height_m, z0), min(b.vz, 0.0), True
        if hit:
            self.collisions += 1
