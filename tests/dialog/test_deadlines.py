"""Deadlines in the dialog: a sentence handed to the drone too long after the operator said it
is not run, is said and audited as expired; a stop always runs. Fakes and virtual clocks."""

from __future__ import annotations

import asyncio
from typing import Any

from server.dialog.manager import DialogManager
from server.graph import Graph
from server.language.nlu import NLU
from server.settings import Settings
from tests.dialog.fakes import FakeDescriber, FakeFlight, FakeStore
from tests.supervisor.snaps import fake_flight_supervisor

NLU_ = NLU()
WALL = 1_800_000_000.0


class Rig:
    def __init__(self, **flight: Any) -> None:
        self.graph = Graph()
        self.t = 0.0
        self.wall = WALL
        self.flight = FakeFlight(**flight)
        self.store = FakeStore()
        self.replies: list[dict[str, Any]] = []
        self.dm = DialogManager(
            self.graph,
            Settings(command_deadline_s=2.0),
            self.flight,
            self.flight,
            FakeDescriber(),
            self.store,
            lambda: self.t,
            nlu=NLU_,
            wall_clock=lambda: self.wall,
        )
        self.graph.subscribe("/console/reply", self.replies.append)
        self.supervisor = fake_flight_supervisor(self.flight)
        self.supervisor.on_alarm(self.dm.hear)

    def run(self, seconds: float, dt: float = 0.1) -> None:
        for _ in range(round(seconds / dt)):
            self.t = round(self.t + dt, 6)
            self.flight.step(self.t)
            self.dm.step(self.t)
            self.supervisor.step(self.t)


async def test_a_late_take_off_is_not_flown_said_and_audited() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("take off", issued=WALL - 5.4)
    assert not res.accepted
    assert res.reply == (
        "Not flown: 'take off' reached the drone 5.4 s after you gave it (deadline 2 s)."
    )
    assert rig.flight.log == []
    assert rig.replies[-1]["level"] == "warn" and rig.replies[-1]["text"] == res.reply
    assert rig.store.rows[-1]["action"] == "expired"
    assert rig.store.rows[-1]["outcome"] == (
        "expired: delivered 5.40 s after it was issued, 3.40 s past the 2 s deadline. " + res.reply
    )


async def test_in_time_it_flies_and_a_late_stop_still_stops() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("take off", issued=WALL - 1.9)
    assert res.accepted and rig.flight.log[-1] == ("submit", {"action": "takeoff"})
    rig.run(2.2)
    res = await rig.dm.handle_utterance("land", issued=WALL - 60.0)
    assert res.accepted and rig.flight.log[-1] == ("preempt", {"action": "land"})


async def test_a_sentence_with_any_motion_expires_whole() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.2)
    res = await rig.dm.handle_utterance("go up 1 meter and then land", issued=WALL - 3.0)
    assert not res.accepted and res.reply.startswith("Not flown: 'go up 1 meter and then land'")
    assert rig.flight.log == [("submit", {"action": "takeoff"})]
    # what moves nothing is answered however late
    res = await rig.dm.handle_utterance("what is the battery", issued=WALL - 60.0)
    assert res.accepted


async def test_a_late_yes_does_not_fly_what_it_confirms() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off", confidence=0.4, source="speech", issued=WALL)
    rig.wall += 4.0
    res = await rig.dm.handle_utterance("yes", source="button", issued=WALL + 1.0)
    assert not res.accepted and res.reply.startswith("Not flown: 'take off' reached the drone 3.0")
    assert rig.flight.log == []


async def test_an_utterance_on_the_graph_is_judged_by_its_issued() -> None:
    rig = Rig()
    rig.graph.advertise("/console/utterance", "uav_console/Utterance")
    utter = {"text": "take off", "confidence": 1.0, "source": "text"}
    rig.graph.publish("/console/utterance", utter, issued=WALL - 2.5)
    await asyncio.gather(*rig.dm._pending)
    assert rig.flight.log == [] and rig.store.rows[-1]["action"] == "expired"
    rig.graph.publish("/console/utterance", utter)  # none: no deadline (a lockstep test)
    await asyncio.gather(*rig.dm._pending)
    assert rig.flight.log == [("submit", {"action": "takeoff"})]
