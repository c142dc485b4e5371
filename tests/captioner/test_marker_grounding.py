"""At marker 3 the description says "marker 3": ids come from the ArUco detector (issue 18).

Lockstep flight with the simulator's camera: take off, fly to marker 3, caption the frame the
camera delivers with the shipped ONNX model, and ground the ids with the detector's markers,
the way ``Runtime.describe`` does.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.captioner import Captioner
from server.captioner.grounding import ground_marker_ids, seen_markers
from server.settings import ROOT
from server.tasks import TaskManager


@pytest.mark.timeout(180)
def test_description_at_marker_3_names_marker_3() -> None:
    world = load_world("indoor")
    rig = LockstepRig(world, seed=3, camera=True)
    frames: list[np.ndarray] = []
    deliver = rig.vehicle.on_frame

    def tap(frame: np.ndarray, t: float) -> None:
        frames.append(frame)
        deliver(frame, t)

    rig.vehicle.on_frame = tap  # type: ignore[method-assign]
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    assert rig.wait_link()
    assert rig.takeoff_all()
    assert all(d.accepted for d in tm.submit([{"action": "goto", "marker": 3}]))
    assert rig.run_until(lambda: tm.status.state == "idle" and not tm.status.queued, 60.0)
    rig.run(0.5)
    seen = seen_markers(rig.vehicle.snapshot())
    assert 3 in [s.id for s in seen], seen
    captioner = Captioner.load(ROOT / "models" / "captioner")
    try:
        raw = captioner.caption(frames[-1]).text
    finally:
        captioner.close()
    text = ground_marker_ids(raw, seen)
    named = {int(n) for n in re.findall(r"\bmarkers? (\d+)", text)}
    named |= {int(n) for n in re.findall(r"\band (\d+) in view", text)}
    assert 3 in named, (raw, text)
    assert named <= {s.id for s in seen}, (raw, text, seen)
