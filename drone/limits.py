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
JOG_SLOW_ZONE_M = 1.0  # within this distance of a limit the jog towards it is scaled down
JOG_STOP_M = 0.15  # this close to a limit the jog towards it stops (and brakes)
JOG_BRAKE_PER_M_S = 0.5  # braking command (fraction) per m/s of speed towards the limit


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

        Per axis and direction: beyond ``JOG_SLOW_ZONE_M`` from the limit the jog passes;
        inside it the component towards the limit scales down linearly, and within
        ``JOG_STOP_M`` (or when the drone could not stop in time at its speed) it becomes a
        brake against the speed towards the limit. Moving away from a limit is never limited.
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
                dist, toward, name = hi - pos, max(vel, 0.0), hi_name
            elif cmd < 0:
                dist, toward, name = pos - lo, max(-vel, 0.0), lo_name
            else:
                out.append(cmd)
                continue
            # words for the operator: a wall's real distance (the fence keeps the margin); the
            # floor and ceiling limits by their height
            if axis == "z":
                where = f"the {name} limit of {hi if cmd > 0 else lo:g} m"
                shown = dist
            else:
                where = f"the {name}" if self.indoor else "the fence"
                shown = dist + m
            scale = 1.0
            if dist < JOG_SLOW_ZONE_M:
                scale = max(0.0, (dist - JOG_STOP_M) / (JOG_SLOW_ZONE_M - JOG_STOP_M))
            # stopping distance at the hover brake's ~1.5 m/s²: v² / (2a)
            if toward * toward / 3.0 > max(dist - JOG_STOP_M, 0.0):
                scale = 0.0
            if scale >= 1.0:
                out.append(cmd)
                continue
            sign = 1.0 if cmd > 0 else -1.0
            if scale <= 0.0:
                out.append(-sign * min(1.0, JOG_BRAKE_PER_M_S * toward))
                reasons.append(f"stopped {max(shown, 0.0):.1f} m from {where}")
            else:
                out.append(cmd * scale)
                reasons.append(f"slowed {max(shown, 0.0):.1f} m from {where}")
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
    )
