"""The position controller of the multimodal-architecture paper, eq. 1, in its own units.

Source: "A Multimodal Control Architecture for Autonomous Unmanned Aerial Vehicles", eq. 1:

    [φ, θ]ᵀ = P_r(ψ) · (0.5 · e_xy  − 0.32 · v_xy)      roll/pitch, fractions of 18°
    ψ̇       = 0.02 · e_ψ[deg]                           yaw rate,   fraction of 90°/s
    ż_cmd   = 0.6 · e_z − 0.2 · ż + 0.01 · ∫ e_z dt     vertical,   fraction of 2 m/s

Sign fix: the paper prints the damping terms with a ``+`` (``+0.32·ẋ``, ``+0.2·ż``). With
e = target − position, a ``+`` on the velocity *adds* to the command in the direction the drone
already moves, i.e. negative damping, and the closed loop is unstable (a pole in the right half
plane: s² − 0.32·k·s + 0.5·k). Damping must oppose velocity, so both terms are subtracted here,
as in tum_ardrone (D term = −velocity; notes/protocols.md).

Conversion to AT*PCMD: the drone's ``euler_angle_max`` (12° indoor), ``control_vz_max``
(700 mm/s) and ``control_yaw`` (100 °/s) are smaller than the paper's 18°, 2 m/s and 90°/s
scales. A paper fraction f is a physical quantity (f·18°, f·2 m/s, f·90°/s); dividing it by the
drone's limit gives the PCMD fraction: tilt ×18/12 = ×1.5, vertical ×2/0.7 ≈ ×2.86, yaw
×90/100 = ×0.9. The result is clamped to [−1, 1] (the planar pair as a vector, so the direction
of travel is kept when the tilt saturates); the drone cannot tilt more than its own limit anyway.
PCMD signs (SDK 2.0 §6.6): pitch < 0 = nose down = forward, roll < 0 = left, yaw > 0 =
clockwise, gaz > 0 = up; REP 103 is forward/left/CCW-positive, hence the negations.

Time is passed in (``dt``), as simple-pid's ``time_fn`` does, so the same object runs in real time
and lockstep. Anti-windup: the integral only accumulates while the vertical output is not
saturated in the direction of the error, and is clamped to ``i_max_frac`` of full scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from drone.control.errors import GainError


def wrap_angle(a: float) -> float:
    """Wrap an angle in radians to [−π, π)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class StateLike(Protocol):
    """What the controller needs from an estimate: map-frame pose and velocity."""

    @property
    def x(self) -> float: ...
    @property
    def y(self) -> float: ...
    @property
    def z(self) -> float: ...
    @property
    def yaw_rad(self) -> float: ...
    @property
    def vx(self) -> float: ...
    @property
    def vy(self) -> float: ...
    @property
    def vz(self) -> float: ...


@dataclass(frozen=True)
class Setpoint:
    """A map-frame target pose. ``yaw_rate_rad_s`` set: ignore ``yaw_rad`` and turn at that rate
    (CCW positive) while holding x, y, z — the tag-search manoeuvre."""

    x: float
    y: float
    z: float
    yaw_rad: float
    yaw_rate_rad_s: float | None = None

    def __post_init__(self) -> None:
        vals = (self.x, self.y, self.z, self.yaw_rad)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"setpoint must be finite, got {vals}")
        if self.yaw_rate_rad_s is not None and not math.isfinite(self.yaw_rate_rad_s):
            raise ValueError("yaw_rate_rad_s must be finite")


@dataclass(frozen=True)
class PaperGains:
    """Gains and output scales of eq. 1 (defaults are the paper's)."""

    kp_xy: float = 0.5  # per metre of planar error
    kd_xy: float = 0.32  # per m/s of planar velocity (damping)
    k_yaw_per_deg: float = 0.02  # per degree of yaw error
    kp_z: float = 0.6  # per metre of height error
    kd_z: float = 0.2  # per m/s of vertical velocity (damping)
    ki_z: float = 0.01  # per metre·second of integrated height error
    tilt_scale_deg: float = 18.0  # roll/pitch full scale
    yaw_scale_deg_s: float = 90.0  # yaw-rate full scale
    vz_scale_m_s: float = 2.0  # vertical-speed full scale
    i_max_frac: float = 0.2  # |ki·∫e| never exceeds this fraction of full scale

    def __post_init__(self) -> None:
        for name, v in vars(self).items():
            if not math.isfinite(v) or v < 0:
                raise GainError(f"gain {name}={v!r} must be finite and >= 0")
        for name in ("tilt_scale_deg", "yaw_scale_deg_s", "vz_scale_m_s"):
            if getattr(self, name) <= 0:
                raise GainError(f"{name} must be > 0")


@dataclass(frozen=True)
class DroneLimits:
    """The drone's own PCMD full scales (AR.Drone 2.0 indoor defaults, SDK 2.0 config keys
    ``control:euler_angle_max``, ``control:control_vz_max``, ``control:control_yaw``)."""

    euler_angle_max_deg: float = 12.0
    control_vz_max_m_s: float = 0.7
    control_yaw_deg_s: float = 100.0

    def __post_init__(self) -> None:
        for name, v in vars(self).items():
            if not math.isfinite(v) or v <= 0:
                raise GainError(f"limit {name}={v!r} must be finite and > 0")


@dataclass(frozen=True)
class PaperOutput:
    """Eq. 1 outputs in REP 103 directions, fractions of the paper's scales, each in [−1, 1]."""

    forward: float  # tilt to accelerate forward (fraction of 18°)
    left: float  # tilt to accelerate left (fraction of 18°)
    yaw_rate: float  # CCW positive (fraction of 90°/s)
    climb: float  # up positive (fraction of 2 m/s)


@dataclass(frozen=True)
class PcmdCommand:
    """AT*PCMD arguments: fractions of the drone's limits, PCMD signs. ``hover``: flag 0."""

    roll: float = 0.0
    pitch: float = 0.0
    gaz: float = 0.0
    yaw: float = 0.0
    hover: bool = False

    @classmethod
    def hold(cls) -> PcmdCommand:
        return cls(hover=True)


def _clamp(v: float, lo: float = -1.0, hi: float = 1.0) -> float:
    return lo if v < lo else hi if v > hi else v


class PaperPID:
    """Eq. 1 with anti-windup; ``step(state, setpoint, dt)`` returns a :class:`PcmdCommand`."""

    def __init__(self, gains: PaperGains | None = None, limits: DroneLimits | None = None) -> None:
        self.gains = gains or PaperGains()
        self.limits = limits or DroneLimits()
        self._integral_z = 0.0  # ∫ e_z dt, metre·seconds
        self.last_output: PaperOutput | None = None

    def reset(self) -> None:
        """Forget the integral (new take-off, new mode)."""
        self._integral_z = 0.0
        self.last_output = None

    @property
    def integral_z(self) -> float:
        return self._integral_z

    def paper_output(self, s: StateLike, sp: Setpoint, dt: float) -> PaperOutput:
        """Eq. 1 (with the damping sign fixed) in the paper's units.

        Raises:
            ValueError: ``dt`` negative or not finite.
        """
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be finite and >= 0, got {dt!r}")
        g = self.gains
        # Planar: u = Kp·e − Kd·v in the map frame, then P_r(ψ): rotate into the body frame.
        ux = g.kp_xy * (sp.x - s.x) - g.kd_xy * s.vx
        uy = g.kp_xy * (sp.y - s.y) - g.kd_xy * s.vy
        c, sn = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
        forward = c * ux + sn * uy
        left = -sn * ux + c * uy
        # Yaw: 0.02 per degree of (wrapped) error, or the commanded search rate.
        if sp.yaw_rate_rad_s is not None:
            yaw_rate = math.degrees(sp.yaw_rate_rad_s) / g.yaw_scale_deg_s
        else:
            yaw_rate = g.k_yaw_per_deg * math.degrees(wrap_angle(sp.yaw_rad - s.yaw_rad))
        # Vertical with conditional integration (anti-windup).
        e_z = sp.z - s.z
        pd = g.kp_z * e_z - g.kd_z * s.vz
        candidate = self._integral_z + e_z * dt
        i_cap = g.i_max_frac / g.ki_z if g.ki_z > 0 else 0.0
        candidate = _clamp(candidate, -i_cap, i_cap)
        unclamped = pd + g.ki_z * candidate
        saturated_same_way = abs(unclamped) > 1.0 and (unclamped > 0) == (e_z > 0)
        if not saturated_same_way:
            self._integral_z = candidate
        climb = pd + g.ki_z * self._integral_z
        out = PaperOutput(
            forward=_clamp(forward),
            left=_clamp(left),
            yaw_rate=_clamp(yaw_rate),
            climb=_clamp(climb),
        )
        self.last_output = out
        return out

    def to_pcmd(self, out: PaperOutput) -> PcmdCommand:
        """Convert paper fractions to PCMD fractions of the drone's limits (module docstring)."""
        g, lim = self.gains, self.limits
        k_tilt = g.tilt_scale_deg / lim.euler_angle_max_deg
        fwd, lft = out.forward * k_tilt, out.left * k_tilt
        norm = math.hypot(fwd, lft)
        if norm > 1.0:  # vector clamp keeps the direction of travel
            fwd, lft = fwd / norm, lft / norm
        return PcmdCommand(
            roll=_clamp(-lft),
            pitch=_clamp(-fwd),
            gaz=_clamp(out.climb * g.vz_scale_m_s / lim.control_vz_max_m_s),
            yaw=_clamp(-out.yaw_rate * g.yaw_scale_deg_s / lim.control_yaw_deg_s),
        )

    def step(self, s: StateLike, sp: Setpoint, dt: float) -> PcmdCommand:
        """One control step: eq. 1 then the PCMD conversion."""
        return self.to_pcmd(self.paper_output(s, sp, dt))
