"""Waypoints by voice outdoors: the dialog, the real task manager and vehicle, in lockstep
against the simulator (the camera on, no surveyed start: the drone finds itself from the markers
at home, as it does live).

A waypoint of a GPS world is flown on the estimate the GPS keeps, never on a marker search; the
operator hears "Flying to waypoint 3.", then that it got there, or why it did not. (The flagship
sentence indoors: ``test_flagship_sentence.py``.)"""

from __future__ import annotations

import math

import pytest

from server.dialog.states import State
from server.fleet.geo import origin_of
from server.fleet.ltm import LocalTaskManager
from server.fleet.stations import station_positions
from tests.dialog.lockstep_dialog import DialogRig, dialog_rig

WP3 = (15.0, 15.0, 2.5)  # worlds/outdoor.yaml wp3


def texts(r: DialogRig) -> list[str]:
    return [str(m["text"]) for m in r.replies]


def idle(r: DialogRig) -> bool:
    return r.tm.current is None and not r.tm.queued


def outdoor(seed: int, **kw: object) -> DialogRig:
    """The outdoor field, the drone on its home pad, its GPS fixes fused by the fleet's local
    task manager (as in every vehicle process)."""
    r = dialog_rig(seed, None, world_name="outdoor", camera=True, known_start=False, **kw)  # type: ignore[arg-type]
    world = r.rig.world
    pad = station_positions(world, 1)[0]
    r.ltm = LocalTaskManager("uav1", r.rig.vehicle, r.tm, pad, origin=origin_of(world))  # type: ignore[attr-defined]
    assert r.rig.wait_link()
    return r


def gps_only(r: DialogRig) -> None:
    """The camera off once the drone has found itself from the markers at home: the GPS keeps
    the position from there (``test_fly_to_waypoint_3_reaches_it_on_gps`` flies the whole way
    with the camera on and checks the markers are never missed). Rendering and reading 15
    frames a second is nearly all of a lockstep flight's time, and the checks after this read
    no frame."""
    assert r.rig.vehicle.snapshot().localised
    r.rig.camera = False


@pytest.mark.timeout(300)
@pytest.mark.parametrize("seed", [1, 2])
async def test_fly_to_waypoint_3_reaches_it_on_gps(seed: int) -> None:
    r = outdoor(seed)
    res = await r.dm.handle_utterance("take off and fly to waypoint 3")
    assert res.accepted and res.reply == "Taking off, then flying to waypoint 3.", res
    assert r.rig.run_until(lambda: idle(r) and r.dm.state is State.AIRBORNE_IDLE, 90.0)
    said = texts(r)
    assert said[-1] == "Reached waypoint 3", said
    assert not any("lost sight" in t or "no longer see" in t for t in said), said
    tr = r.rig.sim.truth
    assert math.dist((tr.x, tr.y, tr.z), WP3) < 0.5, tr
    assert r.ltm.gps_fixes > 10  # type: ignore[attr-defined]  # GPS fixes kept the position
    assert r.rig.sim.physics.collisions == 0


@pytest.mark.timeout(300)
async def test_go_to_wp2_then_patrol_waypoints_1_to_4() -> None:
    r = outdoor(3)
    await r.dm.handle_utterance("take off")
    assert r.rig.run_until(lambda: r.dm.state is State.AIRBORNE_IDLE, 20.0)
    gps_only(r)
    res = await r.dm.handle_utterance("go to wp2")
    assert res.accepted and res.reply == "Flying to waypoint 2.", res
    assert r.rig.run_until(lambda: idle(r), 60.0)
    tr = r.rig.sim.truth
    assert math.dist((tr.x, tr.y), (15.0, -15.0)) < 0.5, tr
    res = await r.dm.handle_utterance("patrol waypoints 1 to 4")
    assert res.accepted and res.reply == "Patrolling waypoints 1, 2, 3 and 4.", res
    n = len(r.replies)
    assert r.rig.run_until(lambda: sum(t.startswith("Reached") for t in texts(r)[n:]) >= 4, 150.0)
    legs = [t for t in texts(r)[n:] if t.startswith("Reached")]
    assert legs[:4] == [f"Reached waypoint {i}." for i in (1, 2, 3, 4)], legs
    assert r.tm.current is not None and r.tm.current.name == "patrol"  # a patrol loops on


@pytest.mark.timeout(300)
async def test_a_named_drone_flies_to_the_waypoint_and_answers_with_its_name() -> None:
    r = outdoor(4, drone="uav2", drones=("uav1", "uav2"))
    await r.dm.handle_utterance("uav2 take off")
    assert r.rig.run_until(lambda: r.dm.state is State.AIRBORNE_IDLE, 20.0)
    gps_only(r)
    res = await r.dm.handle_utterance("drone 2 fly to waypoint 3")
    assert res.accepted and res.reply == "uav2: Flying to waypoint 3.", res
    assert r.rig.run_until(lambda: idle(r), 60.0)
    tr = r.rig.sim.truth
    assert math.dist((tr.x, tr.y, tr.z), WP3) < 0.5, tr


@pytest.mark.timeout(300)
async def test_failures_are_said_with_the_reason() -> None:
    r = outdoor(5)
    await r.dm.handle_utterance("take off")
    assert r.rig.run_until(lambda: r.dm.state is State.AIRBORNE_IDLE, 20.0)
    gps_only(r)
    res = await r.dm.handle_utterance("fly to waypoint 9")
    assert not res.accepted
    assert res.reply == "There is no waypoint 9. Known waypoints: 1, 2, 3, 4."
    # A head wind a little stronger than the drone can fly (top speed ~2.3 m/s): the leg's time
    # limit runs out, and the operator is told where it gave up.
    r.rig.sim.inject_fault("wind", vx=-1.7, vy=-1.7)
    res = await r.dm.handle_utterance("fly to waypoint 3")
    assert res.accepted, res
    assert r.rig.run_until(lambda: idle(r), 200.0)
    failed = [m for m in r.replies if m["text"].startswith("I could not finish")]
    assert len(failed) == 1 and failed[0]["level"] == "warn", texts(r)
    assert "timed out" in failed[0]["text"] and "from waypoint 3" in failed[0]["text"]
    assert r.dm.state is State.AIRBORNE_IDLE
