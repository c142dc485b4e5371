"""Flight limits of a world — fence, floor, ceiling — and the checks every part shares.

DESIGN §5: limits belong to the world, not to a global setting. A room's walls and ceiling are
its limits; an outdoor field states its own (``limits:`` in the world file). Three users:

* planning (the task manager, the central task manager): :meth:`FlightLimits.violation` says
  *why* a target is out of bounds, so a command or a mission is refused up front with that
  reason instead of being cancelled in mid-air;
* the ANS altitude monitor: :attr:`FlightLimits.ceiling_m` of the world being flown;
* the manual jog: :meth:`FlightLimits.clamp_jog` slows and stops a ``/cmd_vel`` jog near a
  wall, the floor or the ceiling and says why.

Defaults (a world file may override each): indoor, the walls less ``wall_margin_m`` (0.35 m:
the AR.Drone's indoor hull is 0.52 m across, plus the position error), the floor plus
``floor_m`` (0.3 m: below it the ultrasound and the ground effect are unreliable) and the
ceiling less 0.3 m (rotor wash against the ceiling pulls the drone up). Outdoor, the field's
bounds and ``ceiling_m`` from the file, else the bounds' top.

Pure functions of numbers: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

WALL_MARGIN_M = 0.35
FLOOR_M = 0.3
CEILING_CLEARANCE_M = 0.3
PERSON_DISTANCE_M = 2.0  # keep-away from people unless the world says otherwise
JOG_SLOW_ZONE_M = 1.0  # within this distance of a limit the jog towards it is scaled down
JOG_STOP_M = 0.15  # this close to a limit the jog towards it stops (and brakes)
JOG_AT_STOP_M = 0.05  # this near the stop line the jog is said to have stopped
JOG_BRAKE_PER_M_S = 2.0  # braking command (fraction) per m/s over the speed allowed
# A full horizontal jog flies at g·tan(12°) / drag ≈ 2.3 m/s (the indoor euler_angle_max and the
# simulator's drag, drone/sim/physics.py); a full vertical one at control_vz_max, 0.7 m/s.
JOG_TOP_SPEED_M_S = 2.3
JOG_TOP_VZ_M_S = 0.7
# Braking the jog plans with: well under the ~2 m/s² a full 12° tilt gives, for the attitude lag
# (0.15 s) and the estimate's.
JOG_DECEL_M_S2 = 1.0
JOG_DECEL_Z_M_S2 = 1.0
JOG_LAG_S = 0.25  # attitude lag (0.15 s) plus the estimate's, before a brake slows the drone


class LimitsError(ValueError):
    """A world's ``limits:`` section is invalid (the message names the field)."""


@dataclass(frozen=True)
class JogClamp:
    """A jog after clamping, in map-frame command fractions, and why it was changed."""

    east: float  # map x fraction
    north: float  # map y fraction
    up: float
    reasons: tuple[str, ...] = ()


@dataclass(frozen=True)
class FlightLimits:
    """Where a drone may be sent in one world (map frame, metres; heights above the floor)."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    floor_m: float  # lowest commanded height above the floor
    ceiling_m: float  # highest commanded height above the floor
    wall_margin_m: float = WALL_MARGIN_M
    indoor: bool = True
    person_distance_m: float = PERSON_DISTANCE_M  # how close to a person a drone may fly

    @property
    def area(self) -> str:
        return "room" if self.indoor else "flying field"

    def violation(self, x: float, y: float, z: float) -> str | None:
        """Why (x, y, z) is outside the limits, in words; None when it is inside."""
        m = self.wall_margin_m
        if not (self.x_min + m <= x <= self.x_max - m and self.y_min + m <= y <= self.y_max - m):
            return (
                f"({x:.1f}, {y:.1f}) is outside the {self.area} "
                f"({self.x_max - self.x_min:.0f} × {self.y_max - self.y_min:.0f} m, "
                f"keeping {m:g} m from its edges)"
            )
        return self.height_violation(z)

    def height_violation(self, z: float) -> str | None:
        """Why height ``z`` is below the floor limit or above the ceiling; None when allowed."""
        if z > self.ceiling_m + 1e-9:
            return (
                f"a height of {z:.1f} m is above this {self.area}'s ceiling of {self.ceiling_m:g} m"
            )
        if z < self.floor_m - 1e-9:
            return f"a height of {z:.1f} m is below the lowest safe height of {self.floor_m:g} m"
        return None

    def vertical_violation(self, z_from: float, z_to: float) -> str | None:
        """Why a straight climb or descent from ``z_from`` to ``z_to`` is refused; None when
        allowed. The fence is not judged (a vertical move never crosses it), and a move towards
        the allowed heights is allowed even where it ends short of them: a drone above the
        ceiling may always descend, one below the floor limit always climb."""
        why = self.height_violation(z_to)
        if why is None:
            return None
        if z_to > self.ceiling_m and z_to < z_from:
            return None
        if z_to < self.floor_m and z_to > z_from:
            return None
        return why

    def clamp_jog(
        self,
        x: float,
        y: float,
        z: float,
        vx: float,
        vy: float,
        vz: float,
        east: float,
        north: float,
        up: float,
    ) -> JogClamp:
        """Limit a map-frame jog (fractions) at position (x, y, z) moving at (vx, vy, vz).

        Per axis and direction, towards a limit: the stop line lies ``JOG_STOP_M`` before the
        limit. Over the slow zone the jog is scaled down linearly to nothing at the stop line.
        The speed allowed is the lower of that ramp's and the speed the drone can still brake
        from before the stop line (``sqrt(2·a·d)``, ``d`` left after ``JOG_LAG_S`` of flight at
        its speed); measured faster than that, the command is that speed's own command less a
        brake on the excess. So a held jog rests on the stop line (within the estimate's
        error) whatever its run-up, without overshooting it.
        Moving away from a limit is never limited.
        """
        m = self.wall_margin_m
        reasons: list[str] = []
        out = []
        for axis, pos, vel, cmd, lo, hi, lo_name, hi_name in (
            ("x", x, vx, east, self.x_min + m, self.x_max - m, "wall", "wall"),
            ("y", y, vy, north, self.y_min + m, self.y_max - m, "wall", "wall"),
            ("z", z, vz, up, self.floor_m, self.ceiling_m, "floor", "ceiling"),
        ):
            if cmd > 0:
                dist, toward, name = hi - pos, vel, hi_name
            elif cmd < 0:
                dist, toward, name = pos - lo, -vel, lo_name
            else:
                out.append(cmd)
                continue
            # words for the operator: a wall's real distance (the fence keeps the margin); the
            # floor and ceiling limits by their height
            if axis == "z":
                where = f"the {name} limit of {hi if cmd > 0 else lo:g} m"
                shown = dist
                top, decel, gain = JOG_TOP_VZ_M_S, JOG_DECEL_Z_M_S2, 0.0
            else:
                where = f"the {name}" if self.indoor else "the fence"
                shown = dist + m
                top, decel, gain = JOG_TOP_SPEED_M_S, JOG_DECEL_M_S2, JOG_BRAKE_PER_M_S
            left = dist - JOG_STOP_M  # to the stop line
            ramp = min(1.0, max(0.0, left / (JOG_SLOW_ZONE_M - JOG_STOP_M)))
            # the drone flies on for ``JOG_LAG_S`` before a brake bites: plan from there
            ahead = left - max(toward, 0.0) * JOG_LAG_S
            allowed = min(top * ramp, math.sqrt(2.0 * decel * max(ahead, 0.0)))
            # the speed's own command (the drone flies at ``top`` on a full command) and a
            # brake on any speed above it (the attitude lags: brake on what is measured)
            mag = abs(cmd) * ramp
            if toward > allowed:
                mag = min(mag, allowed / top + gain * (allowed - toward))
            if mag >= abs(cmd):
                out.append(cmd)
                continue
            sign = 1.0 if cmd > 0 else -1.0
            mag = max(mag, -1.0)
            out.append(sign * mag)
            verb = "stopped" if mag <= 0.0 or left <= JOG_AT_STOP_M else "slowed"
            reasons.append(f"{verb} {max(shown, 0.0):.1f} m from {where}")
        return JogClamp(out[0], out[1], out[2], tuple(reasons))


def limits_of(world: Any) -> FlightLimits:
    """The flight limits of ``world`` (a ``drone.sim.world.World``): its ``limits`` section if it
    has one, else the defaults of the module docstring.

    Raises:
        LimitsError: a value in the world's ``limits`` is not a finite number or the ceiling is
            not above the floor.
    """
    b = world.bounds
    indoor = bool(getattr(world, "indoor", True))
    raw: Mapping[str, Any] = getattr(world, "limits", None) or {}
    height = b.z_max - b.z_min
    default_ceiling = height - CEILING_CLEARANCE_M if indoor else height
    vals: dict[str, float] = {}
    for key, default in (
        ("ceiling_m", default_ceiling),
        ("floor_m", FLOOR_M),
        ("wall_margin_m", WALL_MARGIN_M),
        ("person_distance_m", PERSON_DISTANCE_M),
    ):
        v = raw.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise LimitsError(f"limits.{key}: expected a finite number, got {v!r}")
        vals[key] = float(v)
    if not 0.0 <= vals["floor_m"] < vals["ceiling_m"] <= height:
        raise LimitsError(
            f"limits: need 0 <= floor_m < ceiling_m <= {height:g} (the world's height), "
            f"got floor {vals['floor_m']:g}, ceiling {vals['ceiling_m']:g}"
        )
    return FlightLimits(
        b.x_min,
        b.x_max,
        b.y_min,
        b.y_max,
        vals["floor_m"],
        vals["ceiling_m"],
        vals["wall_margin_m"],
        indoor,
        vals["person_distance_m"],
    )
