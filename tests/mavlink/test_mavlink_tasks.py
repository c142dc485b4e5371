"""One vehicle interface: the task manager and the NLU fly a MAVLink autopilot in lockstep with
the same commands as the AR.Drone — take off, move, turn, "fly to waypoint 3", "patrol
waypoints 1, 2, 3 and 4", hover, return home (the autopilot's RTL), land, emergency ahead of
anything queued, the jog streamed while held and zero on release, and a refused take-off
explained."""

from __future__ import annotations

import math
from typing import Any

import pytest

from drone.mavlink.lockstep import MavlinkLockstepRig
from drone.sim.world import load_world
from server.language.nlu import default_nlu
from server.settings import Settings
from server.tasks.manager import TaskManager


@pytest.fixture(scope="module")
def world() -> Any:
    return load_world("outdoor")


@pytest.fixture(scope="module")
def nlu() -> Any:
    return default_nlu(str(Settings().grammar_dir))


class Flight:
    def __init__(self, world: Any) -> None:
        self.rig = MavlinkLockstepRig(world)
        self.v = self.rig.vehicle
        self.tm = TaskManager(self.v, world, self.rig.clock)
        self.rig.add_stepper(lambda now, dt: self.tm.step(now))
        self.notices: list[Any] = []
        self.tm.on_event(self.notices.append)
        assert self.rig.wait_link()

    def say(self, nlu: Any, text: str, timeout: float = 90.0) -> list[Any]:
        commands = nlu.interpret(text)
        assert commands, text
        decisions = self.tm.submit(commands)
        assert all(d.accepted for d in decisions), decisions
        self.rig.run_until(lambda: self.tm.current is None and not self.tm.queued, timeout)
        return list(commands)

    def at(self) -> tuple[float, float, float]:
        s = self.v.snapshot()
        return s.x, s.y, s.z


def test_words_fly_the_autopilot(world: Any, nlu: Any) -> None:
    f = Flight(world)
    f.say(nlu, "take off")
    s = f.v.snapshot()
    assert s.flying and s.ctrl_state in ("HOVERING", "FLYING") and s.z > 2.0
    assert f.v.protocol.telemetry.mode == "AUTO.LOITER"
    f.say(nlu, "go forward 3 meters")  # start yaw 90°: north, +y
    assert math.dist(f.at()[:2], (0.0, 3.0)) < 0.3
    f.say(nlu, "turn left 90 degrees")
    assert math.degrees(f.v.snapshot().yaw_rad) == pytest.approx(180.0, abs=5.0)
    assert f.v.protocol.telemetry.mode == "OFFBOARD"  # position targets, not attitudes
    cmds = f.say(nlu, "fly to waypoint 3")
    assert cmds == [{"action": "goto", "waypoint": 3}]
    assert math.dist(f.at(), (15.0, 15.0, 2.5)) < 0.3
    assert any(n.text == "Reached waypoint 3" for n in f.notices)
    f.say(nlu, "return home", timeout=120)
    s = f.v.snapshot()
    assert not s.flying and s.ctrl_state == "LANDED"
    assert math.hypot(f.rig.autopilot.physics.body.x, f.rig.autopilot.physics.body.y) < 0.6
    assert f.rig.autopilot.statustexts.count("Takeoff detected") == 1


def test_patrol_waypoints_in_a_loop(world: Any, nlu: Any) -> None:
    f = Flight(world)
    f.say(nlu, "take off")
    cmds = nlu.interpret("patrol waypoints 1, 2, 3 and 4")
    assert cmds == [{"action": "patrol", "waypoints": [1, 2, 3, 4]}]
    assert all(d.accepted for d in f.tm.submit(cmds))
    f.rig.run(100.0)  # 4 sides of 30 m at ≤ 5 m/s, more than once round
    reached = [n.text for n in f.notices if n.kind == "progress"]
    assert reached[:5] == [f"Reached waypoint {i}" for i in (1, 2, 3, 4, 1)]
    assert f.tm.status.name == "patrol"
    f.tm.preempt("hover")
    f.rig.run(3.0)
    assert f.v.protocol.telemetry.mode == "AUTO.LOITER"  # the autopilot's own hold
    here = f.at()
    f.rig.run(2.0)  # holding: the autopilot keeps the position it was given
    assert math.dist(here, f.at()) < 0.1


def test_unknown_waypoint_is_refused(world: Any, nlu: Any) -> None:
    f = Flight(world)
    f.say(nlu, "take off")
    d = f.tm.submit(nlu.interpret("fly to waypoint 9"))
    assert not d[0].accepted
    assert d[0].reason == "There is no waypoint 9. Known waypoints: 1, 2, 3, 4."


def test_emergency_goes_ahead_of_the_queue(world: Any, nlu: Any) -> None:
    f = Flight(world)
    f.say(nlu, "take off")
    f.tm.submit(nlu.interpret("fly to waypoint 1 and then fly to waypoint 2"))
    f.rig.run(1.0)
    f.v.protocol.intent("hold")  # something queued on the link
    f.tm.preempt("emergency")
    f.rig.run(0.1)
    ap = f.rig.autopilot
    assert not ap.armed  # motors off at once (force disarm), not after the queue
    assert f.tm.current is None and not f.tm.queued
    f.rig.run(3.0)
    assert ap.physics.body.z == pytest.approx(0.0)
    assert f.v.snapshot().ctrl_state in ("LANDED", "DEFAULT")


def test_jog_streams_while_held_and_stops_on_release(world: Any, nlu: Any) -> None:
    f = Flight(world)
    f.say(nlu, "take off")
    for _ in range(50):  # 1 s of a held key (the console re-sends /cmd_vel)
        f.v.jog(1.0, 0.0, 0.0, 0.0)
        f.rig.run(0.02)
    ap = f.rig.autopilot
    assert ap.mode == "OFFBOARD" and ap.physics.body.vy > 1.0  # forward = north
    f.v.jog(0.0, 0.0, 0.0, 0.0)
    f.rig.run(3.0)
    assert ap.mode == "AUTO.LOITER"
    assert math.hypot(ap.physics.body.vx, ap.physics.body.vy) < 0.2
    assert f.v.protocol.streaming is None


def test_refused_takeoff_is_explained(world: Any, nlu: Any) -> None:
    f = Flight(world)
    f.rig.autopilot.inject_fault("battery", pct=10.0)
    f.tm.submit(nlu.interpret("take off"))
    f.rig.run(3.0)
    texts = [n.text for n in f.v.drain_notices()]
    assert "The drone refused to take off (denied): Arming denied: low battery." in texts
    assert not f.v.snapshot().flying


def test_patrol_route_as_an_autopilot_mission(world: Any, nlu: Any) -> None:
    f = Flight(world)
    f.say(nlu, "take off")
    f.v.upload_patrol([tuple(map(float, w.position)) for w in world.waypoints])
    f.rig.run(1.0)
    assert "uav1: mission upload ACCEPTED." in [n.text for n in f.v.drain_notices()]
    f.v.start_mission()
    f.rig.run(2.0)
    assert f.rig.autopilot.mode == "AUTO.MISSION"
    f.rig.run_until(lambda: f.rig.autopilot.mode == "AUTO.LOITER" and f.rig.clock.now() > 5, 90)
    assert f.rig.autopilot.mission_current == 4  # all four waypoints flown by the autopilot
    f.rig.run(5.0)  # PX4 loiters at the last waypoint
    assert math.dist(f.at(), tuple(map(float, world.waypoints[3].position))) < 0.3
