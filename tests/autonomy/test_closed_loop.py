"""Closed-loop flights in lockstep: the simulator behind the real wire protocol, rendered camera,
marker perception, EKF, the paper's PID at 100 Hz and the task manager — all on a virtual clock.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drone.sim.world import World, load_world
from tests.autonomy.flight import Flight

LEG_TIME_BOUND_S = 25.0


@pytest.fixture(scope="module")
def world() -> World:
    return load_world("indoor")


# Three seeded start poses (a station and a heading each); together the flights visit all 12
# markers, each leg starting where the previous one ended.
PLANS = [
    (0, (1.0, 3.0, 0.0), [11, 0, 1, 2]),
    (1, (1.0, 2.2, -0.6), [3, 4, 5, 6]),
    (2, (1.0, 3.8, 0.6), [7, 8, 9, 10]),
]


@pytest.mark.parametrize(("seed", "start", "markers"), PLANS)
def test_goto_every_marker_accurately_without_collision(
    world: World, seed: int, start: tuple[float, float, float], markers: list[int]
) -> None:
    f = Flight.make(world, seed=seed, starts=[start])
    f.submit({"action": "takeoff"})
    assert f.run_until_idle(12.0)
    for mid in markers:
        t0 = f.rig.clock.now()
        f.submit({"action": "goto", "marker": mid})
        assert f.run_until_idle(LEG_TIME_BOUND_S), f"marker {mid}: {f.tm.status}"
        assert f.events[-1].kind == "done" and f.events[-1].text == f"Reached marker {mid}"
        sp = world.marker(mid).standoff(1.0)
        d, dyaw = f.truth_error(sp.x, sp.y, sp.z, sp.yaw_rad)
        assert d < 0.15 and dyaw < 5.0, (mid, d, dyaw)  # true pose, not the estimate
        assert f.rig.clock.now() - t0 < LEG_TIME_BOUND_S
    assert f.collisions == 0
    # the EKF stayed consistent along the way: mean NEES of (x, y, z, yaw) at most χ²(4)'s
    # 97.5 % quantile, and it was not wildly over-confident at any sampled instant
    nees = np.array(f.nees)
    assert len(nees) > 100
    assert np.mean(nees) < 11.14, np.mean(nees)
    assert np.mean(nees > 18.47) < 0.05


def test_move_and_turn_in_the_drone_frame(world: World) -> None:
    # On the floor 2 m east of marker 10 (west wall, y = 4.5), facing it.
    f = Flight.make(world, seed=4, starts=[(2.0, 4.5, math.pi)])
    f.submit(
        {"action": "takeoff"},
        {"action": "move", "direction": "backward", "distance": 1.5},  # east, away from the wall
        {"action": "turn", "direction": "left", "angle": 90},  # facing south
        {"action": "move", "direction": "forward", "distance": 1.0},  # south
        {"action": "move", "direction": "up", "distance": 0.3},
    )
    assert f.run_until_idle(60.0), f.tm.status
    assert [e.text for e in f.events if e.kind == "done"] == [
        "Took off",
        "Moved backward 1.5 m",
        "Turned left 90°",
        "Moved forward 1 m",
        "Moved up 0.3 m",
    ]
    z0 = f.rig.sim.truth.z  # "up 0.3" from the take-off height, checked below
    d, dyaw = f.truth_error(3.5, 3.5, z0, -math.pi / 2)
    assert d < 0.15 and dyaw < 5.0
    assert 1.0 < z0 < 1.2  # ~0.8 m take-off height + 0.3 m
    assert f.collisions == 0


def test_tag_search_recovers_when_started_facing_a_wall_without_markers(world: World) -> None:
    # Facing the east wall from 1 m: markers 4 and 5 are 1.5 m to the sides, out of view;
    # the EKF knows nothing (no surveyed start).
    f = Flight.make(world, seed=5, starts=[(7.0, 3.0, 0.0)], known_start=False)
    f.submit({"action": "takeoff"})
    assert f.run_until_idle(12.0)
    assert not f.rig.vehicle.snapshot().localised
    f.submit({"action": "goto", "marker": 6})
    assert f.run_until_idle(60.0), f.tm.status
    kinds = f.kinds()
    assert "searching" in kinds and "marker_found" in kinds
    assert kinds.index("searching") < kinds.index("marker_found") < len(kinds) - 1
    assert next(e.text for e in f.events if e.kind == "searching") == (
        "I lost sight of the markers, searching"
    )
    assert f.events[-1].text == "Reached marker 6"
    sp = world.marker(6).standoff(1.0)
    d, dyaw = f.truth_error(sp.x, sp.y, sp.z, sp.yaw_rad)
    assert d < 0.15 and dyaw < 5.0
    assert f.collisions == 0


def test_a_wind_gust_is_rejected(world: World) -> None:
    f = Flight.make(world, seed=6, starts=[(3.2, 1.1, -math.pi / 2)])  # below marker 1's stand-off
    f.submit({"action": "takeoff"}, {"action": "goto", "marker": 1})
    assert f.run_until_idle(30.0)
    sp = world.marker(1).standoff(1.0)
    f.rig.sim.inject_fault("wind_gust", vx=1.5, vy=0.0, duration_s=1.0)
    f.rig.run(1.0)
    pushed, _ = f.truth_error(sp.x, sp.y, sp.z, sp.yaw_rad)
    assert pushed > 0.15  # the gust really moved it
    f.rig.run(7.0)
    d, dyaw = f.truth_error(sp.x, sp.y, sp.z, sp.yaw_rad)
    assert d < 0.15 and dyaw < 5.0, (pushed, d, dyaw)
    assert f.collisions == 0
