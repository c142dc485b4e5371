"""The vehicle's task ops judge a sentence's deadline as they receive it (server/vehicles/
task_ops.py), on a lockstep drone and its real task executor: a motion past the deadline is
answered ``expired`` and never reaches the executor; a stop always runs."""

from __future__ import annotations

from drone.deadline import Deadline
from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.tasks import TaskManager
from server.vehicles.task_ops import run_task_op

NOW = 1_800_000_000.0
RULE = Deadline(2.0)


def rig() -> tuple[LockstepRig, TaskManager]:
    world = load_world("indoor")
    r = LockstepRig(world, seed=3, camera=False)
    tm = TaskManager(r.vehicle, world, r.clock)

    def step(now: float, dt: float) -> None:
        tm.step(now)

    r.add_stepper(step)
    assert r.wait_link()
    return r, tm


def test_a_late_submit_is_expired_and_never_queued_and_one_in_time_runs() -> None:
    r, tm = rig()
    takeoff = {"commands": [{"action": "takeoff"}]}
    late = run_task_op(tm, "submit", takeoff, issued=NOW - 2.5, now=NOW, deadline=RULE)
    assert late["accepted"] is False
    assert late["expired"] == {"age_s": 2.5, "deadline_s": 2.0}
    assert late["detail"].startswith("Not flown: 'take off' reached the drone 2.5 s after")
    assert late["decisions"] == [{"accepted": False, "reason": late["detail"], "question": False}]
    r.run(2.0)
    assert tm.status.state == "idle" and not r.vehicle.snapshot().flying

    # no issued (a console that sends none): no deadline here; in time: it runs
    in_time = run_task_op(tm, "submit", takeoff, issued=NOW - 1.0, now=NOW, deadline=RULE)
    assert in_time["decisions"][0]["accepted"], in_time
    assert r.run_until(lambda: r.vehicle.snapshot().flying, 20.0)


def test_a_late_stop_always_runs_and_a_late_return_home_does_not() -> None:
    r, tm = rig()
    assert run_task_op(tm, "submit", {"commands": [{"action": "takeoff"}]})["decisions"][0][
        "accepted"
    ]
    assert r.run_until(lambda: r.vehicle.snapshot().flying, 20.0)
    home = {"command": {"action": "return_home"}}
    late_home = run_task_op(tm, "preempt", home, issued=NOW - 30.0, now=NOW, deadline=RULE)
    assert late_home["accepted"] is False and late_home["expired"]["age_s"] == 30.0
    assert "decisions" not in late_home
    land = {"command": {"action": "land"}}
    late_land = run_task_op(tm, "preempt", land, issued=NOW - 30.0, now=NOW, deadline=RULE)
    assert late_land["accepted"], late_land
    assert r.run_until(lambda: not r.vehicle.snapshot().flying, 20.0)
    # cancel never expires either
    assert run_task_op(tm, "cancel", {}, issued=NOW - 30.0, now=NOW, deadline=RULE)["accepted"]
