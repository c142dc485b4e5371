"""Where a fleet's drones are based: the world's home stations, then extra pads for more drones."""

from __future__ import annotations

from typing import Any

from server.fleet.geo import Enu


def station_positions(world: Any, n: int) -> list[Enu]:
    """The world's stations, then extra pads 1.5 m apart south of the home pad for more drones."""
    pads = [Enu(float(s.position[0]), float(s.position[1]), 0.0) for s in world.stations[:n]]
    for k in range(n - len(pads)):
        pads.append(Enu(-3.0 + 1.5 * (k % 5), -2.0 - 1.5 * (k // 5), 0.0))
    return pads
