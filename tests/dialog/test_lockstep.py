"""Dialog + ANS with the real task manager and vehicle, in lockstep against the simulator:
the battery crosses the low threshold mid-task -> a spoken warning and the drone returns home."""

from __future__ import annotations

import pytest

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.dialog.adapters import TaskManagerPort, VehiclePort
from server.dialog.manager import DialogManager
from server.dialog.states import State
from server.graph import Graph
from server.language.nlu import NLU
from server.settings import Settings
from server.store import AuditLog
from server.tasks import TaskManager


@pytest.mark.timeout(120)
async def test_battery_low_mid_task_warns_and_returns_home() -> None:
    world = load_world("indoor")
    rig = LockstepRig(world, seed=3, camera=False, starts=[(4.0, 2.0, 0.0)])
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    graph = Graph()
    replies: list[dict] = []
    graph.subscribe("/console/reply", replies.append, type="uav_console/Reply")
    audit = AuditLog(":memory:", clock=rig.clock.now)
    dm = DialogManager(
        graph,
        Settings(),
        TaskManagerPort(tm),
        VehiclePort(rig.vehicle, world),
        None,
        audit,
        rig.clock.now,
        nlu=NLU(),
    )
    rig.add_stepper(lambda now, dt: dm.step(now))
    assert rig.wait_link()

    refused = await dm.handle_utterance("go forward 1 meter")
    assert not refused.accepted and refused.reply == "I need to take off first."

    res = await dm.handle_utterance("take off")
    assert res.accepted and res.reply == "Taking off."
    assert rig.run_until(lambda: dm.state is State.AIRBORNE_IDLE, 15.0), dm.state
    res = await dm.handle_utterance("turn left 360 degrees and then turn right 360 degrees")
    assert res.accepted, res.reply
    assert rig.run_until(lambda: dm.state is State.EXECUTING, 2.0)
    rig.run(1.0)
    assert tm.current is not None and tm.current.name == "turn"

    rig.sim.physics.battery.drain_to(24.0)  # mid-task
    assert rig.run_until(lambda: dm.state is State.RETURNING, 3.0), dm.state
    warn = [r for r in replies if r["level"] == "warn" and "Battery low" in r["text"]]
    assert len(warn) == 1 and warn[0]["speak"] is True
    assert tm.current is not None and tm.current.name == "return_home"
    assert not tm.queued  # the second turn was preempted
    entry = audit.recent(1)[0]
    assert entry.role == "system" and entry.action == "ans:battery"
