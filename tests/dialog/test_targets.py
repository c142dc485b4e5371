"""Objects as targets, questions back, tag search on request and idle, and the notifications the
operator hears (issue 13 items 6-8): the dialog with the real task manager and vehicle, flown in
lockstep against the simulator with the camera on (marker localisation)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.dialog.adapters import TaskManagerPort, VehicleAdapter
from server.dialog.manager import DialogManager
from server.dialog.states import State
from server.graph import Graph
from server.language.nlu import NLU
from server.settings import Settings
from server.tasks import TaskManager
from server.tasks.objects import STANDOFF_M
from tests.supervisor.snaps import supervised


@dataclass
class Rig:
    rig: LockstepRig
    tm: TaskManager
    dm: DialogManager
    replies: list[dict[str, Any]]
    world: Any

    async def say(self, text: str) -> Any:
        return await self.dm.handle_utterance(text)

    def heard(self, since: int) -> list[str]:
        return [r["text"] for r in self.replies[since:]]

    def idle(self, timeout_s: float = 40.0) -> bool:
        return self.rig.run_until(lambda: self.tm.current is None, timeout_s)


@pytest.fixture
def flying() -> Iterator[Rig]:
    world = load_world("indoor")
    # facing markers 1 and 2 on the south wall, 2 m away: localised from the first frames
    rig = LockstepRig(world, seed=5, camera=True, starts=[(4.0, 2.0, -math.pi / 2)])
    tm = TaskManager(rig.vehicle, world, rig.clock, idle_search=True)
    rig.add_stepper(lambda now, dt: tm.step(now))
    graph = Graph()
    replies: list[dict[str, Any]] = []
    graph.subscribe("/console/reply", replies.append, type="uav_console/Reply")
    dm = DialogManager(
        graph,
        Settings(),
        TaskManagerPort(tm),
        VehicleAdapter(rig.vehicle, world),
        None,
        None,
        rig.clock.now,
        nlu=NLU(),
    )
    rig.add_stepper(lambda now, dt: dm.step(now))
    supervised(rig, tm, world, dm, None)
    assert rig.wait_link()
    r = Rig(rig, tm, dm, replies, world)
    yield r


async def _take_off(r: Rig) -> None:
    res = await r.say("take off")
    assert res.accepted
    assert r.rig.run_until(lambda: r.dm.state is State.AIRBORNE_IDLE, 15.0)


@pytest.mark.timeout(120)
async def test_ambiguous_object_asks_back_then_flies_to_the_answer(flying: Rig) -> None:
    r = flying
    refused = await r.say("fly to the door")
    assert not refused.accepted and refused.reply == "I need to take off first."
    await _take_off(r)

    asked = await r.say("go to the chair")
    assert not asked.accepted
    assert asked.reply == "Which chair? The red one or the blue one?"
    assert r.tm.current is None  # nothing moved
    n = len(r.replies)
    res = await r.say("the red one")
    assert res.accepted and res.reply == "Flying to the red chair."
    assert res.commands == [{"action": "goto", "object": "chair", "colour": "red"}]
    assert r.idle()
    assert "Reached the red chair" in r.heard(n)
    chair = next(o for o in r.world.objects if o.id == "chair1")
    t = r.rig.sim.truth
    cx, cy, _ = chair.centre
    reach = max(chair.size[0], chair.size[1]) / 2 + STANDOFF_M
    assert math.hypot(t.x - cx, t.y - cy) == pytest.approx(reach, abs=0.2)
    facing = math.degrees(math.atan2(cy - t.y, cx - t.x) - t.yaw_rad)
    assert abs((facing + 180) % 360 - 180) < 8  # looking at it

    # an answer with no question, and an answer that does not fit the question
    late = await r.say("the blue one")
    assert not late.accepted and "did not ask" in late.reply
    # a question about one command of a sentence: the answer runs the whole sentence
    asked = await r.say("climb 0.3 meters and then fly to the chair")
    assert asked.reply == "Which chair? The red one or the blue one?"
    n = len(r.replies)
    res = await r.say("the blue one")
    assert res.accepted and res.reply == "Climbing 0.3 meters, then flying to the blue chair."
    assert r.idle()
    assert r.heard(n)[-1] == "Reached the blue chair"
    await r.say("face the window")
    wrong = await r.say("the red one")  # both windows are light blue
    assert not wrong.accepted and "no red window" in wrong.reply
    n = len(r.replies)
    res = await r.say("the north one")  # the question still stands after a wrong answer
    assert res.accepted and res.reply == "Turning to face the north window."
    assert r.idle(20.0)
    assert "Facing the north window" in r.heard(n)
    window = next(o for o in r.world.objects if o.id == "window1")
    t = r.rig.sim.truth
    want = math.atan2(window.centre[1] - t.y, window.centre[0] - t.x)
    assert abs(math.degrees((t.yaw_rad - want + math.pi) % (2 * math.pi) - math.pi)) < 6


@pytest.mark.timeout(120)
async def test_unknown_and_missing_objects_get_a_reason(flying: Rig) -> None:
    r = flying
    await _take_off(r)
    fridge = await r.say("fly to the fridge")
    assert not fridge.accepted
    assert fridge.reply.startswith("I don't know what a fridge is. Here I know a door, two windows")
    car = await r.say("go to the car")  # a kind of the outdoor world, not of this room
    assert not car.accepted and car.reply.startswith("There is no car here.")
    green = await r.say("go to the green chair")
    assert not green.accepted and green.reply == "There is no green chair here; they are blue, red."
    n = len(r.replies)
    near = await r.say("go to the nearest person")  # "which" settles it without a question
    assert near.accepted, near.reply
    assert r.idle()
    assert r.heard(n)[-1].startswith("Reached the")


@pytest.mark.timeout(120)
async def test_search_on_request_reports_what_it_found(flying: Rig) -> None:
    r = flying
    landed = await r.say("search for markers")
    assert not landed.accepted and landed.reply == "I need to take off first."
    await _take_off(r)
    res = await r.say("turn left 90 degrees")  # now facing the west wall's side, no marker
    assert res.accepted
    assert r.idle(20.0)
    n = len(r.replies)
    res = await r.say("look for a tag")
    assert res.accepted and res.reply == "Searching for markers."
    assert r.dm.state is State.SEARCHING
    assert r.idle(40.0)
    found = [t for t in r.heard(n) if t.startswith("Found marker")]
    assert found and "I am at x" in found[0], r.heard(n)
    seen = {int(m.id) for m in r.rig.vehicle.snapshot().markers}
    assert seen and all(str(i) in found[0] for i in seen)
    assert r.rig.run_until(lambda: r.dm.state is State.AIRBORNE_IDLE, 2.0)


@pytest.mark.timeout(120)
async def test_each_marker_reached_on_a_patrol_leg_is_told(flying: Rig) -> None:
    r = flying
    await _take_off(r)
    n = len(r.replies)
    res = await r.say("patrol markers 2 and 1")
    assert res.accepted
    assert r.rig.run_until(
        lambda: sum(t.startswith("Reached marker") for t in r.heard(n)) >= 3, 60.0
    ), r.heard(n)
    legs = [t for t in r.heard(n) if t.startswith("Reached marker")]
    assert legs[:3] == ["Reached marker 2.", "Reached marker 1.", "Reached marker 2."]
    assert all(x["level"] == "info" and x["speak"] for x in r.replies[n:])
    await r.say("cancel")


@pytest.mark.timeout(120)
async def test_idle_search_when_the_pose_grows_uncertain(flying: Rig) -> None:
    r = flying
    await _take_off(r)
    r.rig.run(2.0)
    assert r.rig.vehicle.snapshot().localised
    r.rig.camera = False  # no more marker fixes: dead reckoning only, σ grows while hovering
    n = len(r.replies)
    assert r.rig.run_until(lambda: r.tm.current is not None, 300.0)
    assert r.tm.current is not None and r.tm.current.name == "search"
    s = r.rig.vehicle.snapshot()
    assert s.position_sigma_m > 0.3 or math.degrees(s.yaw_sigma_rad) > 10
    said = r.heard(n)
    assert said == ["My position is uncertain; searching for markers."], said
    r.rig.camera = True
    assert r.idle(30.0)
    assert r.heard(n)[-1].startswith("Found marker")
    # a search that finds nothing gives up once and is not repeated until a marker is seen
    r.rig.camera = False
    assert r.rig.run_until(lambda: r.tm.current is not None, 300.0)
    n = len(r.replies)
    assert r.idle(40.0)
    assert r.heard(n) == [
        "I could not finish the search: no marker in sight after turning around twice."
    ]
    r.rig.run(30.0)
    assert r.tm.current is None
