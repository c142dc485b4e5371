"""`describe` end to end in lockstep: spoken question -> dialog -> ONNX captioner -> reply."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.captioner import Captioner, describe_frame, describe_frame_sync
from server.dialog.adapters import CallableDescriber, TaskManagerPort, VehicleAdapter
from server.dialog.manager import DialogManager
from server.graph import Graph
from server.language.nlu import NLU
from server.settings import ROOT, Settings
from server.store import AuditLog
from server.tasks import TaskManager
from tests.supervisor.snaps import supervised


@pytest.mark.timeout(120)
async def test_what_do_you_see_is_answered_by_the_captioner_from_the_camera() -> None:
    world = load_world("indoor")
    rig = LockstepRig(world, seed=5, camera=True)
    frames: list[np.ndarray] = []
    deliver = rig.vehicle.on_frame

    def tap(frame: np.ndarray, t: float) -> None:  # the frames the vehicle's camera delivers
        frames.append(frame)
        deliver(frame, t)

    rig.vehicle.on_frame = tap  # type: ignore[method-assign]
    captioner = Captioner.load(ROOT / "models" / "captioner")
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    graph = Graph()
    replies: list[dict[str, Any]] = []
    graph.subscribe("/console/reply", replies.append, type="uav_console/Reply")
    dm = DialogManager(
        graph,
        Settings(),
        TaskManagerPort(tm),
        VehicleAdapter(rig.vehicle, world),
        CallableDescriber(lambda: describe_frame(captioner, frames[-1])),
        AuditLog(":memory:", clock=rig.clock.now),
        rig.clock.now,
        nlu=NLU(),
    )
    rig.add_stepper(lambda now, dt: dm.step(now))
    supervised(rig, tm, world, dm, None)
    assert rig.wait_link()
    assert (await dm.handle_utterance("take off")).accepted
    assert rig.takeoff_all()
    rig.run(1.0)
    assert frames, "the camera delivered no frame"

    result = await dm.handle_utterance("what do you see?", confidence=0.9, source="speech")
    assert result.accepted
    assert result.commands == [{"action": "describe"}]
    caption = describe_frame_sync(captioner, frames[-1])
    assert len(caption.split()) >= 3
    assert caption.lower().rstrip(".") in result.reply.lower()
    assert replies[-1]["speak"] is True and replies[-1]["text"] == result.reply
    captioner.close()
