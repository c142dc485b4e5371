"""Relative motion in the drone's own frame: move a distance, turn an angle."""

from __future__ import annotations

import math
from dataclasses import replace

from drone.commands import DIRECTIONS, Move, Turn
from drone.control.pid import Setpoint, wrap_angle
from drone.vehicle import VehicleSnapshot
from server.tasks.base import Context, PlanState, check_inside, need_flying
from server.tasks.errors import CommandError, RefusedError
from server.tasks.legs import LegsTask

DEFAULT_MOVE_M = 1.0
DEFAULT_TURN_DEG = 90.0
MAX_MOVE_M = 20.0


def _offset(direction: str, dist: float, yaw: float) -> tuple[float, float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return {
        "forward": (c * dist, s * dist, 0.0),
        "backward": (-c * dist, -s * dist, 0.0),
        "left": (-s * dist, c * dist, 0.0),
        "right": (s * dist, -c * dist, 0.0),
        "up": (0.0, 0.0, dist),
        "down": (0.0, 0.0, -dist),
    }[direction]


class MoveTask(LegsTask):
    """Relative move in the drone's frame (forward = where its nose points).

    From an unknown position (no marker fix yet, e.g. a sentence said on the ground) only the
    height is judged when it is planned; it starts once the drone knows where it is, and its
    target is judged against the fence then.
    """

    name = "move"
    needs_position = True

    def __init__(self, command: Move) -> None:
        super().__init__(command)
        d = command.direction
        if d is None:
            raise CommandError(f"'move' needs 'direction' in {', '.join(DIRECTIONS)}; got {d!r}")
        self.direction = d
        self.distance = float(DEFAULT_MOVE_M if command.distance is None else command.distance)
        self._from_z = 0.0  # the height the legs start from (legs())
        if not 0 < self.distance <= MAX_MOVE_M:
            raise CommandError(
                f"move distance must be in (0, {MAX_MOVE_M:.0f}] m, got {self.distance}"
            )

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        what = f"move {self.direction} {self.distance:g} m"
        need_flying(p, what)
        dx, dy, dz = _offset(self.direction, self.distance, p.yaw_rad)
        x, y, z = p.x + dx, p.y + dy, max(p.z, 0.8) + dz if dz else p.z
        if self.vertical:  # never across the fence; towards the allowed heights always
            why = ctx.limits.vertical_violation(max(p.z, 0.8), z)
            if why is not None:
                raise RefusedError(f"I can't {what}: {why}.")
        else:
            check_inside(ctx, x, y, z if dz else max(z, ctx.limits.floor_m), what, p.located)
        return replace(p, x=x, y=y, z=z)

    @property
    def vertical(self) -> bool:
        return self.direction in ("up", "down")

    def check_legs(self, ctx: Context, legs: list[Setpoint]) -> str | None:
        sp = legs[-1]
        if self.vertical:
            why = ctx.limits.vertical_violation(self._from_z, sp.z)
        else:
            why = ctx.limits.violation(sp.x, sp.y, sp.z)
        return None if why is None else f"I can't {self.describe()}: {why}"

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        base = s.setpoint if s.setpoint is not None and s.setpoint.yaw_rate_rad_s is None else None
        x, y, z, yaw = (
            (base.x, base.y, base.z, base.yaw_rad) if base else (s.x, s.y, s.z, s.yaw_rad)
        )
        dx, dy, dz = _offset(self.direction, self.distance, yaw)
        self._from_z = z
        return [Setpoint(x + dx, y + dy, z + dz, yaw)], [f"{self.distance:g} m {self.direction}"]

    def describe(self) -> str:
        return f"move {self.direction} {self.distance:g} m"

    def done_text(self) -> str:
        return f"Moved {self.direction} {self.distance:g} m"


class TurnTask(LegsTask):
    """Turn in place; left = counter-clockwise. Large turns fly in legs of at most 90°."""

    name = "turn"

    def __init__(self, command: Turn) -> None:
        super().__init__(command)
        d = command.direction
        if d is None:
            raise CommandError(f"'turn' needs 'direction' left or right; got {d!r}")
        self.direction = d
        self.angle = float(DEFAULT_TURN_DEG if command.angle is None else command.angle)
        if not 0 < self.angle <= 720:
            raise CommandError(f"turn angle must be in (0, 720] degrees, got {self.angle}")

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        need_flying(p, f"turn {self.direction}")
        sign = 1.0 if self.direction == "left" else -1.0
        return replace(p, yaw_rad=wrap_angle(p.yaw_rad + sign * math.radians(self.angle)))

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        base = s.setpoint if s.setpoint is not None and s.setpoint.yaw_rate_rad_s is None else None
        x, y, z, yaw = (
            (base.x, base.y, base.z, base.yaw_rad) if base else (s.x, s.y, s.z, s.yaw_rad)
        )
        sign = 1.0 if self.direction == "left" else -1.0
        n = max(1, math.ceil(self.angle / 90.0))
        step = math.radians(self.angle) / n
        legs = [Setpoint(x, y, z, wrap_angle(yaw + sign * step * (k + 1))) for k in range(n)]
        return legs, [f"turning {self.direction} {self.angle:g}°"] * n

    def describe(self) -> str:
        return f"turn {self.direction} {self.angle:g}°"

    def done_text(self) -> str:
        return f"Turned {self.direction} {self.angle:g}°"
