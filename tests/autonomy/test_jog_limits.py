"""Issue 13 §3: the manual jog (``/cmd_vel``) is clamped near the room's walls, floor and
ceiling, and the operator is told why. Before, a held "forward" flew the drone into the wall."""

from __future__ import annotations

import math

import pytest

from drone.limits import JOG_STOP_M, FlightLimits, limits_of
from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.dialog.adapters import TaskManagerPort, VehicleAdapter
from server.dialog.manager import DialogManager
from server.graph import Graph
from server.settings import Settings
from server.tasks import TaskManager
from tests.supervisor.snaps import supervised


def _rig(start: tuple[float, float, float]) -> tuple[LockstepRig, DialogManager]:
    world = load_world("indoor")
    rig = LockstepRig(world, seed=4, camera=False, starts=[start])
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    dm = DialogManager(
        Graph(), Settings(), TaskManagerPort(tm), VehicleAdapter(rig.vehicle, world), None, None,
        rig.clock.now,
    )  # fmt: skip
    rig.add_stepper(lambda now, dt: dm.step(now))
    supervised(rig, tm, world, dm, None)
    assert rig.takeoff_all()
    return rig, dm


def test_full_forward_jog_stops_short_of_the_wall_and_says_why() -> None:
    rig, dm = _rig((5.0, 3.0, 0.0))  # facing +x, 3 m from the wall at x = 8
    lim = limits_of(rig.world)
    for _ in range(int(8.0 / 0.1)):  # hold "forward" for 8 s (the console re-sends it)
        rig.vehicle.jog(1.0, 0.0, 0.0, 0.0)
        rig.run(0.1)
    tr = rig.sim.truth
    assert rig.sim.physics.collisions == 0  # before: it hit the wall
    assert tr.x <= lim.x_max - lim.wall_margin_m  # inside the fence
    assert tr.x > lim.x_max - lim.wall_margin_m - 0.6  # and it did get close
    assert abs(tr.vx) < 0.1  # holding there
    assert "from the wall" in rig.vehicle.snapshot().jog_limit
    said = [r["text"] for r in dm.replies if r["text"].startswith("Jog limited")]
    assert said and "wall" in said[-1], dm.replies
    rig.vehicle.jog(-1.0, 0.0, 0.0, 0.0)  # backing away is never limited
    rig.run(0.1)
    cmd = rig.vehicle.snapshot().command
    assert cmd is not None and cmd.pitch == pytest.approx(1.0)
    assert rig.vehicle.snapshot().jog_limit == ""


def test_full_up_jog_stops_under_the_ceiling() -> None:
    rig, dm = _rig((4.0, 3.0, 0.0))
    lim = limits_of(rig.world)
    for _ in range(int(6.0 / 0.1)):
        rig.vehicle.jog(0.0, 0.0, 1.0, 0.0)
        rig.run(0.1)
    tr = rig.sim.truth
    assert tr.z <= lim.ceiling_m + 0.05 and tr.z > lim.ceiling_m - 0.5
    assert "from the ceiling" in rig.vehicle.snapshot().jog_limit
    assert any("ceiling" in r["text"] for r in dm.replies if r["text"].startswith("Jog"))


def test_clamp_rules() -> None:
    lim = FlightLimits(0.0, 8.0, 0.0, 6.0, 0.3, 2.7)
    free = lim.clamp_jog(4.0, 3.0, 1.0, 0.0, 0.0, 0.0, 1.0, -1.0, 0.5)
    assert (free.east, free.north, free.up, free.reasons) == (1.0, -1.0, 0.5, ())
    slow = lim.clamp_jog(7.1, 3.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)  # 0.55 m from the fence
    assert 0.0 < slow.east < 1.0 and slow.reasons == ("slowed 0.9 m from the wall",)
    # fast towards the wall: brakes even outside the stop distance
    brake = lim.clamp_jog(6.8, 3.0, 1.0, 1.5, 0.0, 0.0, 1.0, 0.0, 0.0)
    assert brake.east < 0.0 and brake.reasons[0].startswith("stopped")
    down = lim.clamp_jog(4.0, 3.0, 0.3 + JOG_STOP_M / 2, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0)
    assert down.up == 0.0 and down.reasons == ("stopped 0.1 m from the floor limit of 0.3 m",)
    assert not math.isnan(lim.clamp_jog(-1, -1, -1, 0, 0, 0, -1, -1, -1).east)


# The README's promise: indoors the walls less 0.35 m (the fence), and the jog stops 0.15 m
# before the fence, so a held jog rests 0.50 m from the wall.
PROMISED_STOP_FROM_WALL_M = 0.35 + JOG_STOP_M
# The estimate the clamp steers by is off from the truth by up to a few centimetres (EKF on
# marker fixes); the drone must never come closer than this to the wall, and rest within
# this of the promised line.
ESTIMATE_SLACK_M = 0.05


@pytest.mark.parametrize(
    ("start", "jog", "wall"),
    [
        ((4.0, 3.0, 0.0), (1.0, 0.0), "x_max"),  # 4 m run-up: full speed (finding 9: 0.28 m)
        ((5.0, 3.0, 0.0), (1.0, 0.0), "x_max"),  # 3 m run-up
        ((6.5, 3.0, 0.0), (1.0, 0.0), "x_max"),  # starts inside the slow zone
        ((4.0, 3.0, math.pi / 2), (1.0, 0.0), "y_max"),  # facing the north wall, 3 m
        ((4.0, 3.0, 0.0), (0.0, -1.0), "y_min"),  # sideways jog (right) to the south wall
    ],
)
def test_held_jog_rests_where_the_readme_says(
    start: tuple[float, float, float], jog: tuple[float, float], wall: str
) -> None:
    """Hold a full jog towards a wall through the real jog path (``Vehicle.jog`` → clamp →
    AT*PCMD → simulator): the drone's true closest approach and its resting distance are
    0.35 + 0.15 m from the wall."""
    rig, _dm = _rig(start)
    lim = limits_of(rig.world)

    def gap() -> float:
        t = rig.sim.truth
        return {
            "x_max": lim.x_max - t.x,
            "y_max": lim.y_max - t.y,
            "y_min": t.y - lim.y_min,
        }[wall]

    closest = math.inf
    for _ in range(int(10.0 / 0.1)):  # held 10 s, re-sent every 0.1 s as the console does
        rig.vehicle.jog(jog[0], jog[1], 0.0, 0.0)
        rig.run(0.1)
        closest = min(closest, gap())
    assert rig.sim.physics.collisions == 0
    assert closest >= PROMISED_STOP_FROM_WALL_M - ESTIMATE_SLACK_M, closest
    assert abs(gap() - PROMISED_STOP_FROM_WALL_M) <= ESTIMATE_SLACK_M, gap()
    assert math.hypot(rig.sim.truth.vx, rig.sim.truth.vy) < 0.05  # at rest there
