"""Task manager: validation before moving, queueing, cancel, preemption, jog, the state table.

Runs in lockstep without the camera (the EKF dead-reckons from the surveyed start), which is
all these rules need."""

from __future__ import annotations

import math

import pytest

from drone.sim.world import World, load_world
from server.tasks.build import build_task
from server.tasks.errors import CommandError, IllegalTransition
from server.tasks.states import TRANSITIONS, TaskEvent, TaskState, transition
from tests.autonomy.flight import Flight


@pytest.fixture(scope="module")
def world() -> World:
    return load_world("indoor")


@pytest.fixture
def flying(world: World) -> Flight:
    f = Flight.make(world, seed=11, camera=False, starts=[(4.0, 2.0, 0.0)])
    f.submit({"action": "takeoff"})
    assert f.run_until_idle(12.0)
    return f


def test_state_table_is_the_one_place_transitions_live() -> None:
    assert transition(TaskState.QUEUED, TaskEvent.START) is TaskState.RUNNING
    assert transition(TaskState.RUNNING, TaskEvent.LOST) is TaskState.SEARCHING
    assert transition(TaskState.SEARCHING, TaskEvent.FOUND) is TaskState.RUNNING
    for terminal in (TaskState.SUCCEEDED, TaskState.FAILED, TaskState.CANCELLED):
        assert terminal.terminal and TRANSITIONS[terminal] == {}
        with pytest.raises(IllegalTransition):
            transition(terminal, TaskEvent.START)
    with pytest.raises(IllegalTransition):
        transition(TaskState.QUEUED, TaskEvent.SUCCEED)


@pytest.mark.parametrize(
    ("command", "why"),
    [
        ({"action": "fly_to_the_moon"}, "unknown action"),
        ({}, "unknown action"),
        ({"action": "goto"}, "needs 'marker'"),
        ({"action": "goto", "marker": "3"}, "must be an integer"),
        ({"action": "move", "direction": "sideways"}, "direction"),
        ({"action": "move", "direction": "up", "distance": -1}, "distance"),
        ({"action": "move", "direction": "up", "distance": float("nan")}, "finite"),
        ({"action": "turn", "direction": "up"}, "left or right"),
        ({"action": "patrol", "markers": []}, "non-empty"),
        ({"action": "waypoints", "waypoints": "here"}, "non-empty list"),
    ],
)
def test_malformed_commands_raise_command_error(command: dict, why: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(CommandError, match=why):
        build_task(command)


def test_refusals_come_before_the_drone_moves(flying: Flight) -> None:
    f, tm = flying, flying.tm
    before = f.rig.sim.truth
    cases = [
        ([{"action": "goto", "marker": 42}], "There is no marker 42"),
        ([{"action": "move", "direction": "forward", "distance": 5.0}], "outside the room"),
        ([{"action": "move", "direction": "up", "distance": 3.0}], "height"),
        ([{"action": "hover"}, {"action": "goto", "marker": 49}], "no marker 49"),
        ([{"action": "bogus"}], "unknown action"),
        ("not a list of dicts", "unknown action"),
    ]
    for commands, why in cases:
        decisions = tm.submit(commands)  # type: ignore[arg-type]
        assert decisions and not any(d.accepted for d in decisions)
        assert any(why in d.reason for d in decisions), decisions
        assert tm.current is None and not tm.queued
    # a sentence with one bad command runs none of it
    d = tm.submit([{"action": "move", "direction": "left"}, {"action": "goto", "marker": 99}])
    assert [x.accepted for x in d] == [False, False]
    assert d[0].reason.startswith("not run: There is no marker 99")
    f.rig.run(2.0)
    after = f.rig.sim.truth
    assert math.dist((before.x, before.y), (after.x, after.y)) < 0.05
    assert f.rig.vehicle.setpoint is None


def test_not_flying_is_refused_but_takeoff_first_is_fine(world: World) -> None:
    f = Flight.make(world, seed=12, camera=False)
    d = f.tm.submit([{"action": "move", "direction": "forward", "distance": 1.0}])
    assert not d[0].accepted and "not flying" in d[0].reason
    d = f.tm.submit([{"action": "takeoff"}, {"action": "move", "direction": "up", "distance": 0.5}])
    assert all(x.accepted for x in d)
    assert f.run_until_idle(20.0)
    assert [e.text for e in f.events if e.kind == "done"] == ["Took off", "Moved up 0.5 m"]


def test_queue_cancel_and_jog(flying: Flight) -> None:
    f, tm = flying, flying.tm
    f.submit({"action": "move", "direction": "left", "distance": 1.0})
    f.submit({"action": "turn", "direction": "right", "angle": 45})
    f.rig.run(0.5)
    assert tm.status.name == "move" and tm.status.queued == 1
    assert tm.cancel()
    assert tm.current is None and not tm.queued
    assert f.events[-1].kind == "cancelled"
    sp = f.rig.vehicle.setpoint
    assert sp is not None  # holds where it was
    f.submit({"action": "turn", "direction": "left", "angle": 90})
    f.rig.run(0.3)
    f.rig.vehicle.jog(0.2, 0.0, 0.0, 0.0)  # the operator takes over
    assert tm.current is None
    assert f.events[-1].text.endswith("manual control took over")
    assert f.rig.vehicle.snapshot().mode == "manual"
    f.rig.vehicle.jog(0.0, 0.0, 0.0, 0.0)  # all zero: hover
    assert f.rig.vehicle.snapshot().mode == "idle"


def test_land_preempts_a_patrol_and_reaches_the_driver_at_once(flying: Flight) -> None:
    f, tm = flying, flying.tm
    f.submit({"action": "patrol", "markers": [1, 2]})
    f.rig.run(1.0)
    assert tm.status.name == "patrol"
    decision = tm.preempt("land")
    assert decision.accepted
    # the AT*REF without the take-off bit is already what the driver sends next
    now = f.rig.clock.now()
    assert f.rig.links[0].protocol.next_deadline(now) == now  # land jumped the queue
    assert [(e.kind, e.task) for e in f.events[-2:]] == [
        ("preempted", "patrol"),
        ("started", "land"),
    ]
    assert f.run_until_idle(15.0)
    assert f.events[-1].text == "Landed"
    assert not f.rig.sim.truth.flying
    assert not tm.preempt("goto").accepted


def test_a_sentence_starting_with_land_preempts_but_later_land_waits(flying: Flight) -> None:
    f, tm = flying, flying.tm
    f.submit({"action": "move", "direction": "left", "distance": 0.5}, {"action": "land"})
    f.rig.run(0.2)
    assert tm.status.name == "move" and tm.queued[0].name == "land"
    assert f.run_until_idle(25.0)
    assert [e.text for e in f.events if e.kind == "done"][-2:] == ["Moved left 0.5 m", "Landed"]


def test_query_and_cancel_in_a_sentence(flying: Flight) -> None:
    tm = flying.tm
    d = tm.submit([{"action": "query", "item": "battery"}])
    assert d[0].accepted and d[0].task_id is None
    flying.submit({"action": "turn", "direction": "left", "angle": 30})
    d = tm.submit([{"action": "cancel"}])
    assert d[0].accepted and tm.current is None and not tm.queued


def test_describe_uses_the_hook_or_is_refused(flying: Flight) -> None:
    tm = flying.tm
    d = tm.submit([{"action": "describe"}])
    assert not d[0].accepted and "no captioner" in d[0].reason
    tm.describe_hook = lambda snap: f"I see a wall at {snap.altitude_m:.1f} m"
    flying.submit({"action": "describe"})
    flying.rig.step()
    assert flying.events[-1].kind == "done" and flying.events[-1].text.startswith("I see a wall")


def test_waypoints_in_the_map_frame(flying: Flight) -> None:
    flying.submit(
        {"action": "waypoints", "waypoints": [{"x": 5.0, "y": 2.0, "z": 1.2}, {"x": 5.0, "y": 3.0}]}
    )
    assert flying.run_until_idle(40.0)
    assert flying.events[-1].text == "Reached all 2 waypoints"
    d, _ = flying.truth_error(5.0, 3.0, 1.0, 0.0)
    assert d < 0.2  # dead reckoning only in this test (no camera)
    bad = flying.tm.submit([{"action": "waypoints", "waypoints": [{"lat": 36.0, "lon": 127.0}]}])
    assert not bad[0].accepted and "GPS origin" in bad[0].reason
