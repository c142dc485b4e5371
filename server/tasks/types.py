"""Task types: one class per DESIGN §4 command, each a sequence of setpoints with arrival rules.

A task is planned before the drone moves (``plan``: raises ``RefusedError`` with a reason a
person can read; returns the predicted state after it, so "take off and go to marker 3" checks
the second command against a flying drone), then started and stepped by the ``TaskManager``.

Arrival (tum_ardrone's rule, tightened as issue 4 asks): within ``pos_tol_m`` (0.15 m, 3-D) and
``yaw_tol_deg`` (5°) of the target, then staying inside for ``dwell_s`` (1 s); leaving resets the
dwell. Each leg has a time limit of ``20 s + 4 s/m``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from drone.commands import (
    DIRECTIONS,
    Command,
    Goto,
    Land,
    Move,
    Patrol,
    Turn,
    Waypoint,
    Waypoints,
    wire,
)
from drone.control.pid import Setpoint, wrap_angle
from drone.limits import FlightLimits
from drone.vehicle import Vehicle, VehicleSnapshot
from server.tasks.errors import CommandError, RefusedError
from server.tasks.states import TaskState

_ids = itertools.count(1)

CRUISE_Z_M = 1.0  # height for return home and other legs without a stated height
RTL_TIMEOUT_S = 300.0  # an autopilot's own return to launch (MAVLink): 120 m at 1 m/s and back
MIN_Z_M = 0.3
DEFAULT_MOVE_M = 1.0
DEFAULT_TURN_DEG = 90.0
MAX_MOVE_M = 20.0
SEARCH_RATE_RAD_S = 0.5  # ~29°/s: a full turn in 12.6 s, slow enough for the detector
SEARCH_MAX_TURNS = 2.0


@dataclass(frozen=True)
class ArrivalRule:
    pos_tol_m: float = 0.15
    yaw_tol_deg: float = 5.0
    dwell_s: float = 1.0


@dataclass(frozen=True)
class PlanState:
    """What the drone is predicted to be doing when a queued command starts."""

    flying: bool
    x: float
    y: float
    z: float
    yaw_rad: float
    # Whether x, y are a known position (a marker fix, or a target the plan flies to); before
    # the first fix the estimate's (0, 0) is no position, so no fence can be judged from it.
    located: bool = True


@dataclass(frozen=True)
class Outcome:
    ok: bool
    text: str


class Context:
    """What tasks use from the manager (the manager implements it)."""

    vehicle: Vehicle
    world: Any
    arrival: ArrivalRule
    margin_m: float
    ceiling_m: float
    limits: FlightLimits
    describe_hook: Callable[[VehicleSnapshot], str] | None

    def snapshot(self) -> VehicleSnapshot:  # pragma: no cover - interface
        raise NotImplementedError

    def emit(self, kind: str, text: str) -> None:  # pragma: no cover - interface
        raise NotImplementedError


class Task:
    """Base class: subclasses set ``name`` and override ``plan``/``start``/``step``."""

    name = "task"
    # Needs a confident position from markers while it flies (the manager searches when lost).
    needs_localisation = False
    # Needs a known position (at least one marker fix) before its setpoints are computed: the
    # manager searches for a marker first when the drone has never had one (a move taken from
    # the unlocalised estimate would aim at a made-up place and jump with the first fix).
    needs_position = False

    def __init__(self, command: Command) -> None:
        self.id = next(_ids)
        self.command = wire(command)  # as said, for the dialog's replies and the status
        self.state = TaskState.QUEUED
        self.progress = 0.0
        self.detail = ""
        self.result = ""
        self.started_at: float | None = None
        self.target: Setpoint | None = None  # the setpoint to restore after a search

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        """Check the command against the predicted state; return the state after it.

        Raises:
            RefusedError: it cannot be done (the message says why).
        """
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        self.started_at = now
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        return None

    def describe(self) -> str:
        return self.name


def _need_flying(p: PlanState, what: str) -> None:
    if not p.flying:
        raise RefusedError(f"I can't {what}: I'm not flying. Say 'take off' first.")


def _inside(ctx: Context, x: float, y: float, z: float, what: str, located: bool = True) -> None:
    """Refuse up front a target outside the world's limits (fence, floor, ceiling).

    ``located`` False: (x, y) come from no known position, so only the height is judged here;
    the task judges the fence when it starts, from where the drone then is.
    """
    why = ctx.limits.violation(x, y, z) if located else ctx.limits.height_violation(z)
    if why is not None:
        raise RefusedError(f"I can't {what}: {why}.")


class _Leg:
    """One setpoint with the arrival rule and a time limit."""

    def __init__(self, sp: Setpoint, rule: ArrivalRule, start_pose: VehicleSnapshot, now: float):
        self.sp = sp
        self.rule = rule
        dist = math.dist((start_pose.x, start_pose.y, start_pose.z), (sp.x, sp.y, sp.z))
        self.deadline = now + 20.0 + 4.0 * dist
        self.dist0 = max(dist, 1e-6)
        self.inside_since: float | None = None

    def error(self, s: VehicleSnapshot) -> tuple[float, float]:
        d = math.dist((s.x, s.y, s.z), (self.sp.x, self.sp.y, self.sp.z))
        dyaw = abs(math.degrees(wrap_angle(self.sp.yaw_rad - s.yaw_rad)))
        return d, dyaw

    def arrived(self, s: VehicleSnapshot, now: float) -> bool:
        d, dyaw = self.error(s)
        if d <= self.rule.pos_tol_m and dyaw <= self.rule.yaw_tol_deg:
            if self.inside_since is None:
                self.inside_since = now
            return now - self.inside_since >= self.rule.dwell_s
        self.inside_since = None
        return False

    def progress(self, s: VehicleSnapshot) -> float:
        d, _ = self.error(s)
        return max(0.0, min(1.0, 1.0 - d / self.dist0))

    def pause(self, dt: float) -> None:
        """Extend the time limit (time spent searching does not count)."""
        self.deadline += dt
        self.inside_since = None


class LegsTask(Task):
    """A task made of setpoint legs flown in order (goto, move, turn, patrol, waypoints…)."""

    loop = False
    arrival: ArrivalRule | None = None  # overrides the manager's rule (e.g. outdoor tolerance)

    def __init__(self, command: Command) -> None:
        super().__init__(command)
        self._legs: list[Setpoint] = []
        self._labels: list[str] = []
        self._own: list[int | None] = []  # each leg's index among the task's own (None: detour)
        self._i = 0
        self._leg: _Leg | None = None
        self.lap = 0

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        raise NotImplementedError

    def done_text(self) -> str:
        return f"{self.describe()}: done"

    def check_legs(self, ctx: Context, legs: list[Setpoint]) -> str | None:
        """Why the legs, computed when the task starts, cannot be flown (None: they can)."""
        return None

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        if not s.flying:
            return Outcome(False, "I'm not flying")
        if self.needs_position and not s.localised:
            self.detail = "finding my position first"
            return None  # the manager searches; the legs are computed once a marker is seen
        return self._first_leg(ctx, s, now)

    def _first_leg(self, ctx: Context, s: VehicleSnapshot, now: float) -> Outcome | None:
        self._legs, self._labels = self.legs(ctx, s)
        why = self.check_legs(ctx, self._legs)
        if why is not None:
            return Outcome(False, why)
        self._own = list(range(len(self._legs)))
        keep = getattr(ctx, "keep_away", None)  # round the people a leg passes too close to
        if keep is not None:
            way = keep.reroute((s.x, s.y), self._legs, loop=self.loop)
            if isinstance(way, str):
                return Outcome(False, way)
            labels = self._labels
            self._labels = [
                labels[i] if i is not None else f"going round {who}"
                for i, who in zip(way.origin, way.around, strict=True)
            ]
            self._legs, self._own = way.legs, way.origin
        self._begin_leg(ctx, s, now)
        return None

    def _begin_leg(self, ctx: Context, s: VehicleSnapshot, now: float) -> None:
        sp = self._legs[self._i]
        self._leg = _Leg(sp, self.arrival or ctx.arrival, s, now)
        self.target = sp
        ctx.vehicle.set_setpoint(sp)
        self.detail = self._labels[self._i]

    def pause(self, dt: float) -> None:
        if self._leg is not None:
            self._leg.pause(dt)

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        if not s.flying:
            return Outcome(False, "the drone is no longer flying")
        if self._leg is None:  # started before the drone knew its position (needs_position)
            if not s.localised:
                return None
            return self._first_leg(ctx, s, now)
        leg = self._leg
        n = len(self._legs)
        self.progress = (self._i + leg.progress(s)) / n
        if now > leg.deadline:
            d, dyaw = leg.error(s)
            off = f", {dyaw:.0f}° off its heading" if dyaw > leg.rule.yaw_tol_deg else ""
            return Outcome(False, f"timed out {d:.1f} m from {self._labels[self._i]}{off}")
        if not leg.arrived(s, now):
            return None
        own = self._own[self._i] if self._i < len(self._own) else self._i
        if own is not None:  # a detour round a person is no leg of the task's own
            self.on_leg_done(ctx, own)
        self._i += 1
        if self._i >= n:
            if not self.loop:
                self.progress = 1.0
                return Outcome(True, self.done_text())
            self._i = 0
            self.lap += 1
        self._begin_leg(ctx, s, now)
        return None

    def on_leg_done(self, ctx: Context, i: int) -> None:
        pass


class TakeoffTask(Task):
    name = "takeoff"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        return replace(p, flying=True, z=max(p.z, 0.8))

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        if s.flying:
            return Outcome(True, "Already flying")
        if s.emergency:
            return Outcome(False, "the drone is in emergency; reset it first")
        ctx.vehicle.takeoff()
        self.detail = "taking off"
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        assert self.started_at is not None
        self.progress = min(1.0, s.altitude_m / 0.8)
        if s.flying and s.ctrl_state in ("HOVERING", "FLYING"):
            return Outcome(True, "Took off")
        if now - self.started_at > 10.0:
            return Outcome(False, f"take-off did not finish within 10 s (state {s.ctrl_state})")
        return None


class LandTask(Task):
    name = "land"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        return replace(p, flying=False, z=0.0)

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        ctx.vehicle.land()
        self.detail = "landing"
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        assert self.started_at is not None
        if not s.flying and s.ctrl_state in ("LANDED", "DEFAULT"):
            return Outcome(True, "Landed")
        if now - self.started_at > 15.0:
            return Outcome(False, f"landing did not finish within 15 s (state {s.ctrl_state})")
        return None


class EmergencyTask(Task):
    name = "emergency"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        return replace(p, flying=False, z=0.0)

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        ctx.vehicle.emergency()
        return Outcome(True, "Motors cut (emergency)")


class HoverTask(Task):
    name = "hover"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        _need_flying(p, "hover")
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        # A vehicle whose autopilot holds position (MAVLink) hovers in its own hold mode; the
        # others hold the estimate with the position controller when they know where they are.
        if s.localised and not ctx.vehicle.holds_position:
            ctx.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad))
        else:
            ctx.vehicle.hover()
        return Outcome(True, "Hovering")


class GotoMarkerTask(LegsTask):
    """Fly to a marker's stand-off pose, or to a GPS world's numbered waypoint.

    A marker is flown to on marker localisation (the manager searches when the markers are
    lost); a waypoint of a GPS world is flown on the estimate the GPS keeps (no marker search),
    once the drone knows where it is.
    """

    name = "goto"
    needs_localisation = True
    needs_position = True
    standoff_m = 1.0

    def __init__(self, command: Goto) -> None:
        super().__init__(command)
        # "waypoint": the world's numbered waypoint (GPS worlds); a marker elsewhere.
        self.waypoint: int | None = None
        if command.marker is None and command.waypoint is not None:
            self.waypoint = command.waypoint
        elif command.marker is None:
            raise CommandError("'goto' needs 'marker' or 'waypoint'")
        self.marker = command.marker if command.marker is not None else command.waypoint
        self.kind = "marker" if self.waypoint is None else "waypoint"

    def _standoff(self, ctx: Context) -> Setpoint:
        if self.waypoint is not None and _has_waypoints(ctx):
            self.kind = "waypoint"
            self.needs_localisation = False  # the GPS keeps the position, not the markers
            x, y, z = _world_waypoint(ctx, self.waypoint)
            return Setpoint(x, y, z, ctx.snapshot().yaw_rad)
        self.kind = "marker"
        self.needs_localisation = True
        try:
            m = ctx.world.marker(self.marker)
        except KeyError:
            known = ", ".join(str(i) for i in ctx.world.marker_ids())
            raise RefusedError(
                f"There is no marker {self.marker}. Known markers: {known}."
            ) from None
        p = m.standoff(self.standoff_m)
        return Setpoint(float(p.x), float(p.y), float(p.z), float(p.yaw_rad))

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        sp = self._standoff(ctx)
        _need_flying(p, f"go to {self.kind} {self.marker}")
        _inside(ctx, sp.x, sp.y, sp.z, f"go to {self.kind} {self.marker}")
        return replace(p, x=sp.x, y=sp.y, z=sp.z, yaw_rad=sp.yaw_rad, located=True)

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        return [self._standoff(ctx)], [f"{self.kind} {self.marker}"]

    def describe(self) -> str:
        return f"go to {self.kind} {self.marker}"

    def done_text(self) -> str:
        return f"Reached {self.kind} {self.marker}"


def _has_waypoints(ctx: Context | None) -> bool:
    return ctx is not None and bool(getattr(ctx.world, "waypoints", ()))


def _world_waypoint(ctx: Context, n: int) -> tuple[float, float, float]:
    """Waypoint ``n`` of a GPS world (``wpN``, or the n-th in the file), map frame.

    Raises:
        RefusedError: no such waypoint (the reply lists the known ones).
    """
    wps = ctx.world.waypoints
    for w in wps:
        if w.id in (f"wp{n}", str(n)):
            return float(w.position[0]), float(w.position[1]), float(w.position[2])
    known = ", ".join(w.id.removeprefix("wp") for w in wps)
    raise RefusedError(f"There is no waypoint {n}. Known waypoints: {known}.")


class PatrolTask(LegsTask):
    name = "patrol"
    needs_localisation = True
    needs_position = True
    loop = True

    def __init__(self, command: Patrol) -> None:
        super().__init__(command)
        by_waypoint = command.markers is None and command.waypoints is not None
        ids = command.waypoints if by_waypoint else command.markers
        if not ids:
            raise CommandError("'patrol' needs 'markers', a non-empty list of marker ids")
        self.markers = list(ids)
        self._gotos = [
            GotoMarkerTask(Goto(waypoint=m) if by_waypoint else Goto(marker=m))
            for m in self.markers
        ]

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        for g in self._gotos:
            p = g.plan(p, ctx)
        self.needs_localisation = any(g.needs_localisation for g in self._gotos)
        return p

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        legs = [g._standoff(ctx) for g in self._gotos]
        self.needs_localisation = any(g.needs_localisation for g in self._gotos)
        return legs, [f"{g.kind} {g.marker}" for g in self._gotos]

    def on_leg_done(self, ctx: Context, i: int) -> None:
        ctx.emit("progress", f"Reached {self._gotos[i].kind} {self.markers[i]}")

    def describe(self) -> str:
        return f"patrol {self._gotos[0].kind}s " + ", ".join(str(m) for m in self.markers)


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
        if not 0 < self.distance <= MAX_MOVE_M:
            raise CommandError(
                f"move distance must be in (0, {MAX_MOVE_M:.0f}] m, got {self.distance}"
            )

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        what = f"move {self.direction} {self.distance:g} m"
        _need_flying(p, what)
        dx, dy, dz = _offset(self.direction, self.distance, p.yaw_rad)
        x, y, z = p.x + dx, p.y + dy, max(p.z, 0.8) + dz if dz else p.z
        _inside(ctx, x, y, z if dz else max(z, ctx.limits.floor_m), what, p.located)
        return replace(p, x=x, y=y, z=z)

    def check_legs(self, ctx: Context, legs: list[Setpoint]) -> str | None:
        sp = legs[-1]
        why = ctx.limits.violation(sp.x, sp.y, sp.z)
        return None if why is None else f"I can't {self.describe()}: {why}"

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        base = s.setpoint if s.setpoint is not None and s.setpoint.yaw_rate_rad_s is None else None
        x, y, z, yaw = (
            (base.x, base.y, base.z, base.yaw_rad) if base else (s.x, s.y, s.z, s.yaw_rad)
        )
        dx, dy, dz = _offset(self.direction, self.distance, yaw)
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
        _need_flying(p, f"turn {self.direction}")
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


class ReturnHomeTask(LegsTask):
    """Fly to the home station at cruise height, then land on it."""

    name = "return_home"
    needs_localisation = True

    def __init__(self, command: Command) -> None:
        super().__init__(command)
        self._landing: LandTask | None = None
        self._rtl = False

    def start(self, ctx: Context, now: float) -> Outcome | None:
        rtl = getattr(ctx.vehicle, "return_home", None)
        if rtl is None:
            return super().start(ctx, now)
        # An autopilot (MAVLink) flies its own return to launch: climb, fly home, land.
        Task.start(self, ctx, now)
        if not ctx.snapshot().flying:
            return Outcome(False, "I'm not flying")
        rtl()
        self._rtl = True
        self.detail = "returning to launch"
        return None

    def _home(self, ctx: Context, x: float, y: float) -> Any:
        stations = getattr(ctx.world, "stations", ())
        if not stations:
            raise RefusedError("This world has no home station to return to.")
        return min(stations, key=lambda st: math.hypot(st.position[0] - x, st.position[1] - y))

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        _need_flying(p, "return home")
        h = self._home(ctx, p.x, p.y)
        return replace(p, flying=False, x=h.position[0], y=h.position[1], z=0.0, located=True)

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        h = self._home(ctx, s.x, s.y)
        sp = Setpoint(float(h.position[0]), float(h.position[1]), CRUISE_Z_M, s.yaw_rad)
        return [sp], [f"home station {h.id}"]

    def step(self, ctx: Context, now: float) -> Outcome | None:
        if self._rtl:
            s = ctx.snapshot()
            assert self.started_at is not None
            if not s.flying and s.ctrl_state in ("LANDED", "DEFAULT"):
                return Outcome(True, "Back home and landed")
            if now - self.started_at > RTL_TIMEOUT_S:
                return Outcome(False, f"return to launch did not finish in {RTL_TIMEOUT_S:.0f} s")
            return None
        if self._landing is not None:
            out = self._landing.step(ctx, now)
            if out is not None and out.ok:
                return Outcome(True, "Back home and landed")
            return out
        out = super().step(ctx, now)
        if out is not None and out.ok:
            self._landing = LandTask(Land())
            self.detail = "landing at home"
            return self._landing.start(ctx, now)
        return out

    def describe(self) -> str:
        return "return home"


class WaypointsTask(LegsTask):
    """Fly map-frame (``x, y, z``) or geodetic (``lat, lon, alt``) waypoints in order.

    Command: ``{"action": "waypoints", "waypoints": [{"x":…, "y":…, "z":…} | {"lat":…, "lon":…,
    "alt":…}, …], "loop": false, "tolerance_m": 0.15, "yaw_deg": optional heading}``. Geodetic
    points need the world's ``gps_origin`` (local ENU by pymap3d). A waypoint may carry its own
    ``yaw_deg`` (the fleet's indoor patrol faces each marker). Used by the fleet manager.
    """

    name = "waypoints"

    def __init__(self, command: Waypoints) -> None:
        super().__init__(command)
        self.raw: list[Waypoint] = list(command.waypoints)
        self.loop = bool(command.loop)
        self.tolerance_m = float(command.tolerance_m) if command.tolerance_m else None
        self.yaw_deg = None if command.yaw_deg is None else float(command.yaw_deg)
        self.points: list[tuple[float, float, float]] | None = None

    def _resolve(self, ctx: Context) -> list[tuple[float, float, float]]:
        out = []
        origin = getattr(ctx.world, "gps_origin", None)
        for w in self.raw:
            if w.lat is not None and w.lon is not None:
                if origin is None:
                    raise RefusedError("This world has no GPS origin for lat/lon waypoints.")
                import pymap3d

                e, n, u = pymap3d.geodetic2enu(
                    float(w.lat),
                    float(w.lon),
                    float(origin.alt_m + CRUISE_Z_M if w.alt is None else w.alt),
                    origin.lat_deg,
                    origin.lon_deg,
                    origin.alt_m,
                )
                out.append((float(e), float(n), float(u)))
            else:
                assert w.x is not None and w.y is not None  # Waypoint's own rule
                z = CRUISE_Z_M if w.z is None else w.z
                out.append((float(w.x), float(w.y), float(z)))
        return out

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        _need_flying(p, "fly the waypoints")
        self.points = self._resolve(ctx)
        for k, (x, y, z) in enumerate(self.points):
            _inside(ctx, x, y, z, f"fly to waypoint {k + 1}")
        x, y, z = self.points[-1]
        self.needs_localisation = bool(getattr(ctx.world, "indoor", False) and ctx.world.markers)
        return replace(p, x=x, y=y, z=z, located=True)

    def start(self, ctx: Context, now: float) -> Outcome | None:
        if self.tolerance_m:
            self.arrival = replace(ctx.arrival, pos_tol_m=self.tolerance_m)
        return super().start(ctx, now)

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        pts = self.points or self._resolve(ctx)
        legs = []
        px, py = s.x, s.y
        for k, (x, y, z) in enumerate(pts):
            own = self.raw[k].yaw_deg if k < len(self.raw) else None
            yaw = (
                math.radians(own)  # this waypoint's own heading
                if own is not None
                else math.radians(self.yaw_deg)
                if self.yaw_deg is not None
                else math.atan2(y - py, x - px)
            )
            legs.append(Setpoint(x, y, z, yaw))
            px, py = x, y
        return legs, [f"waypoint {k + 1}/{len(pts)}" for k in range(len(pts))]

    def describe(self) -> str:
        return f"fly {len(self.raw)} waypoints"

    def done_text(self) -> str:
        return f"Reached all {len(self.raw)} waypoints"


class SearchTask(Task):
    """Turn in place (holding height) until a marker is seen (tag search, on request, or by
    the task manager while idle when the pose is uncertain); reports what it found and where
    that puts the drone."""

    name = "search"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        _need_flying(p, "search for markers")
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        s = ctx.snapshot()
        self._t0_marker = s.last_marker_t
        ctx.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad, SEARCH_RATE_RAD_S))
        self.detail = "turning to find a marker"
        return None

    def step(self, ctx: Context, now: float) -> Outcome | None:
        s = ctx.snapshot()
        assert self.started_at is not None
        if s.markers and s.last_marker_t is not None and s.last_marker_t != self._t0_marker:
            ctx.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad))
            ids = sorted({int(m.id) for m in s.markers})
            which = (
                f"marker {ids[0]}"
                if len(ids) == 1
                else "markers " + ", ".join(map(str, ids[:-1])) + f" and {ids[-1]}"
            )
            return Outcome(True, f"Found {which}; I am at x {s.x:.1f}, y {s.y:.1f} meters")
        limit = SEARCH_MAX_TURNS * 2 * math.pi / SEARCH_RATE_RAD_S
        self.progress = min(1.0, (now - self.started_at) / limit)
        if now - self.started_at > limit:
            return Outcome(False, "no marker in sight after turning around twice")
        return None


class DescribeTask(Task):
    """Hands the current view to the describe hook (the captioner) and reports its sentence."""

    name = "describe"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        if ctx.describe_hook is None:
            raise RefusedError("I can't describe the view: no captioner is loaded.")
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        assert ctx.describe_hook is not None
        try:
            text = ctx.describe_hook(ctx.snapshot())
        except Exception as exc:  # the captioner failing must not kill the task manager
            return Outcome(False, f"describing failed: {exc}")
        return Outcome(True, text)
