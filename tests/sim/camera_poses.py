"""Seeded camera poses for the renderer and detector equivalence tests: a third facing a marker
from 0.2-6 m at up to ±80° off its normal, a third hovering low over the floor (tiles and
furniture fill the frame), a third anywhere in the world looking anywhere."""

from __future__ import annotations

import math

import numpy as np

from drone.sim.world import World

Pose = tuple[float, float, float, float, float, float]


def seeded_poses(world: World, n: int, seed: int) -> list[Pose]:
    """``n`` poses ``(x, y, z, roll, pitch, yaw)`` in ``world``, the same for the same seed."""
    rng = np.random.default_rng(seed)
    b = world.bounds
    top = min(b.z_max, b.z_min + 10.0)
    out: list[Pose] = []
    for k in range(n):
        kind = k % 3
        if kind == 0 and world.markers:
            m = world.markers[int(rng.integers(len(world.markers)))]
            d = rng.uniform(0.2, 6.0)
            off = rng.uniform(-1.4, 1.4)
            normal_yaw = math.atan2(m.normal[1], m.normal[0])
            x = m.position[0] + d * math.cos(normal_yaw + off)
            y = m.position[1] + d * math.sin(normal_yaw + off)
            z = m.position[2] + rng.uniform(-1.0, 1.0)
            yaw = math.atan2(m.position[1] - y, m.position[0] - x) + rng.uniform(-0.9, 0.9)
        elif kind == 1:
            x, y = rng.uniform(b.x_min, b.x_max), rng.uniform(b.y_min, b.y_max)
            z = b.z_min + rng.uniform(0.0, 1.5)
            yaw = rng.uniform(-math.pi, math.pi)
        else:
            x, y = rng.uniform(b.x_min, b.x_max), rng.uniform(b.y_min, b.y_max)
            z, yaw = rng.uniform(b.z_min, top), rng.uniform(-math.pi, math.pi)
        roll, pitch = rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)
        out.append((float(x), float(y), float(z), float(roll), float(pitch), float(yaw)))
    return out
