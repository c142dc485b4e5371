"""The flagship sentence indoors: the dialog, the real task manager and vehicle, in lockstep
against the simulator (the camera on, no surveyed start: the drone finds itself from the markers,
as it does live).

"take off, climb one meter and then fly to marker 3" said on the ground, before the first marker
fix, is flown every time: the climb is judged against the fence when it starts, not from the
estimate's made-up (0, 0) of before; a move planned without a position is judged when it runs."""

from __future__ import annotations

import math

import pytest

from server.dialog.states import State
from tests.dialog.lockstep_dialog import DialogRig, dialog_rig


def texts(r: DialogRig) -> list[str]:
    return [str(m["text"]) for m in r.replies]


def idle(r: DialogRig) -> bool:
    return r.tm.current is None and not r.tm.queued


# (x, y, yaw) on the floor: facing the east wall 1 m away, with no marker in view (the drone
# must search once airborne); and in the middle of the west end, markers in view.
BARE_WALL = (7.0, 3.0, 0.0)
IN_VIEW = (1.0, 3.0, 0.0)


@pytest.mark.timeout(300)
@pytest.mark.parametrize(("seed", "start"), [(0, BARE_WALL), (1, BARE_WALL), (2, IN_VIEW)])
async def test_the_flagship_sentence_said_on_the_ground_is_flown_every_time(
    seed: int, start: tuple[float, float, float]
) -> None:
    # No surveyed start and no marker seen yet: the estimate is still (0, 0), a corner of the
    # room outside the fence, when the sentence is said.
    r = dialog_rig(seed, start, camera=True, known_start=False)
    assert r.rig.wait_link()
    if start == BARE_WALL:
        assert not r.rig.vehicle.snapshot().localised
    res = await r.dm.handle_utterance("take off, climb one meter and then fly to marker 3")
    assert res.accepted, res
    assert res.reply == "Taking off, then climbing 1 meter, then flying to marker 3."
    assert r.rig.run_until(lambda: idle(r) and r.dm.state is State.AIRBORNE_IDLE, 90.0)
    said = texts(r)
    assert said[-1] == "Reached marker 3", said
    assert not any(t.startswith("I could not") for t in said), said
    sp = r.rig.world.marker(3).standoff(1.0)
    tr = r.rig.sim.truth
    assert math.dist((tr.x, tr.y, tr.z), (sp.x, sp.y, sp.z)) < 0.2, tr
    assert r.rig.sim.physics.collisions == 0


@pytest.mark.timeout(300)
async def test_a_move_planned_without_a_position_is_judged_at_execution() -> None:
    # 3 m forward of (7, 3) facing east is outside the room: unknown when it is said on the
    # ground, refused with the reason once the drone has found itself, and not flown.
    r = dialog_rig(0, BARE_WALL, camera=True, known_start=False)
    assert r.rig.wait_link()
    assert not r.rig.vehicle.snapshot().localised
    res = await r.dm.handle_utterance("take off and go forward 3 meters")
    assert res.accepted, res
    assert r.rig.run_until(lambda: idle(r), 60.0)
    failed = [t for t in texts(r) if t.startswith("I could not finish")]
    assert len(failed) == 1 and "outside the room" in failed[0], texts(r)
    tr = r.rig.sim.truth
    assert tr.flying and math.hypot(tr.x - 7.0, tr.y - 3.0) < 0.5, tr  # it stayed there
    assert r.rig.sim.physics.collisions == 0
