"""The world's objects as targets (the multimodal paper's Fig. 3 rule 2 and its
OBJECTS mapping): "fly to the door", "go to the red chair", "face the window".

A command names an object by kind (``object``), optionally ``colour`` and ``which`` (nearest,
farthest, or the north/south/east/west one, in the map frame of docs/CONVENTIONS.md). The world
(``GET /world`` ``objects``) holds their poses. :func:`resolve` picks exactly one object or
raises a :class:`RefusedError` with the reason a person can act on:

* a kind the world does not hold ("There is no sofa here. Here I know a door, two windows…");
* a word that is no object kind at all ("I don't know what a fridge is…");
* several that fit: :class:`AmbiguousObjectError`, whose reason is a question ("Which chair?
  The red one or the blue one?") and whose ``question`` flag lets the dialog take the next
  answer ("the red one") as the missing slot.

``GotoObjectTask`` flies to a stand-off pose in front of the object, facing it: for a door or
window (on a wall) along the way it faces; for anything standing in the room, on the side the
drone comes from, turned around the object in 30° steps until the pose is inside the room.
``FaceObjectTask`` turns in place to face the object's centre.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from drone.commands import Goto, Turn
from drone.control.pid import Setpoint, wrap_angle
from drone.vehicle import VehicleSnapshot
from server.tasks.base import MIN_Z_M, Context, PlanState, check_inside, need_flying
from server.tasks.errors import CommandError, RefusedError
from server.tasks.legs import LegsTask

KNOWN_KINDS = frozenset(
    {"chair", "table", "door", "window", "person", "plant", "box", "sofa", "shelf", "lamp"}
    | {"tree", "car", "post"}
)
"""Every kind the worlds can hold (drone/sim/world.py OBJECT_KINDS)."""
WALL_KINDS = frozenset({"door", "window"})  # approached from the side they face
WHICH = ("nearest", "farthest", "north", "south", "east", "west")
STANDOFF_M = 1.0  # clear of the object's footprint, as a marker's stand-off
CRUISE_MIN_Z_M = 1.0
CRUISE_MAX_Z_M = 2.5  # under the ANS ceiling (2.8 m default) wherever the object's centre is
_NUMBERS = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six"}


class AmbiguousObjectError(RefusedError):
    """Several objects fit; ``reason`` is the question to ask, ``options`` what fits."""

    question = True

    def __init__(self, reason: str, options: Sequence[Any]) -> None:
        super().__init__(reason)
        self.options = tuple(options)


def _text(v: str | None) -> str | None:
    """A slot's word as the world names it (the union has checked it is a non-empty string)."""
    return None if v is None else v.strip().lower()


def _plural(kind: str, n: int) -> str:
    word = f"{kind}es" if kind.endswith(("s", "x", "sh", "ch")) else f"{kind}s"
    if kind == "person":
        word = "people"
    if kind == "shelf":
        word = "shelves"
    return f"{_NUMBERS.get(n, str(n))} {word}" if n > 1 else f"a {kind}"


def inventory(world: Any) -> str:
    """ "a door, two windows and a table" — what a person can ask for in this world."""
    counts = Counter(o.kind for o in getattr(world, "objects", ()))
    parts = [_plural(k, n) for k, n in counts.items()]
    if not parts:
        return "nothing"
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def label(obj: Any, world: Any) -> str:
    """How to name ``obj`` to the operator: "the door", "the red chair", "the north window"."""
    same = [o for o in world.objects if o.kind == obj.kind]
    if len(same) == 1:
        return f"the {obj.kind}"
    if sum(1 for o in same if o.colour == obj.colour) == 1:
        return f"the {obj.colour} {obj.kind}"
    return f"the {_side(obj, same)} {obj.kind}"


def _side(obj: Any, group: Sequence[Any]) -> str:
    """The compass side that sets ``obj`` apart in ``group`` (the axis of widest spread)."""
    xs = [o.position[0] for o in group]
    ys = [o.position[1] for o in group]
    if max(ys) - min(ys) >= max(xs) - min(xs):
        mid = (max(ys) + min(ys)) / 2
        return "north" if obj.position[1] > mid else "south"
    mid = (max(xs) + min(xs)) / 2
    return "east" if obj.position[0] > mid else "west"


def _question(kind: str, cands: Sequence[Any], world: Any) -> str:
    colours = [o.colour for o in cands]
    if len(set(colours)) == len(cands):
        opts = [f"the {c} one" for c in colours]
    else:
        sides = [_side(o, cands) for o in cands]
        opts = [f"the {s} one" for s in sides] if len(set(sides)) == len(cands) else []
    if not opts:
        return f"Which {kind}? There are {len(cands)}; say the nearest or the farthest."
    listed = opts[0] if len(opts) == 1 else ", ".join(opts[:-1]) + " or " + opts[-1]
    return f"Which {kind}? {listed[:1].upper()}{listed[1:]}?"


def resolve(world: Any, cmd: Goto | Turn, x: float, y: float) -> Any:
    """The one object ``cmd`` names, seen from ``(x, y)`` (for nearest/farthest).

    Raises:
        CommandError: malformed slots; RefusedError: none fits; AmbiguousObjectError: several.
    """
    kind = _text(cmd.object)
    if kind is None:
        raise CommandError(f"'{cmd.action}' needs 'object' or 'marker'")
    colour = _text(cmd.colour)
    which = _text(cmd.which)
    if which is not None and which not in WHICH:
        raise CommandError(f"'which' must be one of {', '.join(WHICH)}; got {which!r}")
    objects = list(getattr(world, "objects", ()))
    cands = [o for o in objects if o.kind == kind]
    if not cands:
        here = inventory(world)
        if kind not in KNOWN_KINDS:
            raise RefusedError(f"I don't know what a {kind} is. Here I know {here}.")
        raise RefusedError(f"There is no {kind} here. Here I know {here}.")
    if colour is not None:
        fits = [o for o in cands if o.colour == colour]
        if not fits:
            have = sorted({o.colour for o in cands})
            raise RefusedError(
                f"There is no {colour} {kind} here; "
                + (
                    f"the {kind} is {have[0]}."
                    if len(cands) == 1
                    else f"they are {', '.join(have)}."
                )
            )
        cands = fits
    if which is not None and len(cands) > 1:

        def key(o: Any) -> float:
            ox, oy = float(o.position[0]), float(o.position[1])
            return {
                "nearest": math.hypot(ox - x, oy - y),
                "farthest": -math.hypot(ox - x, oy - y),
                "north": -oy,
                "south": oy,
                "east": -ox,
                "west": ox,
            }[which]

        cands = [min(cands, key=key)]
    if len(cands) > 1:
        raise AmbiguousObjectError(_question(kind, cands, world), cands)
    return cands[0]


def _needs_localisation(world: Any) -> bool:
    return bool(getattr(world, "indoor", False) and getattr(world, "markers", ()))


def standoff(obj: Any, ctx: Context, x: float, y: float) -> Setpoint:
    """A pose clear of ``obj`` facing its centre, inside the room (see the module docstring).

    Raises:
        RefusedError: no such pose inside the room.
    """
    cx, cy, cz = obj.centre
    reach = max(obj.size[0], obj.size[1]) / 2.0 + STANDOFF_M
    if obj.kind in WALL_KINDS:
        base = obj.yaw_rad
    elif math.hypot(x - cx, y - cy) > 1e-3:
        base = math.atan2(y - cy, x - cx)
    else:
        base = obj.yaw_rad
    z = min(max(cz, CRUISE_MIN_Z_M, MIN_Z_M), CRUISE_MAX_Z_M, ctx.ceiling_m)
    b = ctx.world.bounds
    m = ctx.margin_m
    for k in (0, 1, -1, 2, -2, 3, -3, 4, -4, 5, -5, 6):
        a = base + math.radians(30.0 * k)
        px, py = cx + reach * math.cos(a), cy + reach * math.sin(a)
        if b.x_min + m <= px <= b.x_max - m and b.y_min + m <= py <= b.y_max - m:
            return Setpoint(px, py, z, wrap_angle(a + math.pi))
    raise RefusedError(f"I can't get near the {obj.kind}: there is no room around it.")


class GotoObjectTask(LegsTask):
    """Fly to an object of the world (``{"action": "goto", "object": "chair", ...}``)."""

    name = "goto"

    def __init__(self, command: Goto) -> None:
        super().__init__(command)
        if command.object is None:
            raise CommandError(f"'{command.action}' needs 'object' or 'marker'")
        self.cmd = command
        self.obj: Any = None
        self.what = f"the {command.object}"
        self._sp: Setpoint | None = None

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        self.obj = resolve(ctx.world, self.cmd, p.x, p.y)
        self.what = label(self.obj, ctx.world)
        need_flying(p, f"fly to {self.what}")
        sp = standoff(self.obj, ctx, p.x, p.y)
        check_inside(ctx, sp.x, sp.y, sp.z, f"fly to {self.what}")
        self._sp = sp
        self.needs_localisation = _needs_localisation(ctx.world)
        return replace(p, x=sp.x, y=sp.y, z=sp.z, yaw_rad=sp.yaw_rad)

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        if self.obj is None:
            self.obj = resolve(ctx.world, self.cmd, s.x, s.y)
        sp = self._sp or standoff(self.obj, ctx, s.x, s.y)
        return [sp], [self.what]

    def describe(self) -> str:
        return f"fly to {self.what}"

    def done_text(self) -> str:
        return f"Reached {self.what}"


class FaceObjectTask(LegsTask):
    """Turn in place to face an object (``{"action": "turn", "object": "window", ...}``)."""

    name = "turn"

    def __init__(self, command: Turn) -> None:
        super().__init__(command)
        if command.object is None:
            raise CommandError(f"'{command.action}' needs 'object' or 'marker'")
        self.cmd = command
        self.obj: Any = None
        self.what = f"the {command.object}"

    @staticmethod
    def _yaw(obj: Any, x: float, y: float) -> float:
        cx, cy, _ = obj.centre
        return math.atan2(cy - y, cx - x)

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        self.obj = resolve(ctx.world, self.cmd, p.x, p.y)
        self.what = label(self.obj, ctx.world)
        need_flying(p, f"face {self.what}")
        return replace(p, yaw_rad=self._yaw(self.obj, p.x, p.y))

    def legs(self, ctx: Context, s: VehicleSnapshot) -> tuple[list[Setpoint], list[str]]:
        base = s.setpoint if s.setpoint is not None and s.setpoint.yaw_rate_rad_s is None else None
        x, y, z = (base.x, base.y, base.z) if base else (s.x, s.y, s.z)
        if self.obj is None:
            self.obj = resolve(ctx.world, self.cmd, x, y)
        return [Setpoint(x, y, z, self._yaw(self.obj, x, y))], [f"turning to {self.what}"]

    def describe(self) -> str:
        return f"face {self.what}"

    def done_text(self) -> str:
        return f"Facing {self.what}"
