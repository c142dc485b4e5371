"""Where the world's people are at a given time: each person with a ``walk`` goes from their
``position`` through the walk's path and back, again and again; the others stand still.

A pure function of the world and the time: every drone's simulator (and the lockstep rig's
several) agree on where a person is. The walking speed is the walk's, varied by up to ±10 %
from its ``seed``.
"""

from __future__ import annotations

import itertools
import math
import random
from dataclasses import dataclass
from typing import Any

SPEED_SPREAD = 0.1  # ±10 % around the world file's speed


@dataclass(frozen=True)
class PersonPose:
    """One person, map frame (metres)."""

    id: str
    x: float
    y: float


def _route(start: tuple[float, float], path: tuple[tuple[float, float], ...]) -> list[Any]:
    there = [start, *path]
    return there + there[-2::-1]  # and back the same way, ending where it began


def _along(points: list[tuple[float, float]], s: float) -> tuple[float, float]:
    for (x0, y0), (x1, y1) in itertools.pairwise(points):
        seg = math.hypot(x1 - x0, y1 - y0)
        if s <= seg and seg > 0.0:
            f = s / seg
            return x0 + f * (x1 - x0), y0 + f * (y1 - y0)
        s -= seg
    return points[-1]


def person_at(obj: Any, t: float) -> PersonPose:
    """Where person ``obj`` (a ``SceneObject`` of kind person) is at time ``t`` (s)."""
    x, y = float(obj.position[0]), float(obj.position[1])
    walk = obj.walk
    if walk is None:
        return PersonPose(obj.id, x, y)
    points = _route((x, y), walk.path)
    length = sum(math.dist(a, b) for a, b in itertools.pairwise(points))
    if length <= 0.0:
        return PersonPose(obj.id, x, y)
    speed = walk.speed_m_s * random.Random(walk.seed).uniform(1 - SPEED_SPREAD, 1 + SPEED_SPREAD)
    px, py = _along(points, (speed * max(t, 0.0)) % length)
    return PersonPose(obj.id, px, py)


def people_at(world: Any, t: float) -> tuple[PersonPose, ...]:
    """Every person of ``world`` at time ``t``."""
    return tuple(person_at(o, t) for o in getattr(world, "objects", ()) if o.kind == "person")
