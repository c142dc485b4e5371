"""What the operator hears about markers and searches (issue 13 item 8), and the Central patrol
by voice with a fake fleet: the dialog manager with the in-memory fakes of tests/dialog."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from server.dialog.ports import TaskReport
from server.dialog.states import State
from tests.dialog.test_manager import Rig


def _emit(rig: Rig, kind: str, action: str, text: str) -> None:
    for cb in rig.flight._callbacks:
        cb(TaskReport(kind, {"action": action}, text))


async def test_search_started_found_and_gave_up_are_spoken() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(3.0)
    await rig.dm.handle_utterance("go to marker 3")
    rig.run(0.5)
    assert rig.dm.state is State.EXECUTING
    n = len(rig.replies)
    _emit(rig, "marker_lost", "goto", "I lost sight of the markers, searching")
    assert rig.dm.state is State.SEARCHING
    _emit(rig, "marker_found", "goto", "Found marker 4; carrying on")
    assert rig.dm.state is State.EXECUTING
    _emit(rig, "progress", "patrol", "Reached marker 2")
    said = [(r["level"], r["text"]) for r in rig.replies[n:]]
    assert said == [
        ("warn", "I lost sight of the markers, searching."),
        ("info", "Found marker 4; carrying on."),
        ("info", "Reached marker 2."),
    ]
    _emit(rig, "failed", "search", "no marker in sight after turning around twice")
    assert rig.replies[-1]["text"] == (
        "I could not finish the search: no marker in sight after turning around twice."
    )


async def test_no_search_claimed_while_the_task_manager_does_not_search() -> None:
    """The drone flies on its estimate without markers for a while: the ANS says the markers
    are out of sight, never that it is searching (it is not), and says when one is back."""
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(3.0)
    rig.flight.task_s = 30.0
    await rig.dm.handle_utterance("go to marker 3")
    rig.run(3.0)
    texts = [r["text"] for r in rig.replies]
    lost = [t for t in texts if ("marker" in t and "sight" in t) or "no longer see" in t]
    assert lost == ["I can no longer see any marker; flying on my own estimate."], texts
    assert not any("search" in t.lower() for t in texts)
    rig.flight.snap = replace(rig.flight.snap, visible_markers=(3,))
    rig.run(1.0)
    assert rig.replies[-1]["text"] == "I can see marker 3 again."


@dataclass
class FakeCentral:
    live: list[str] = field(default_factory=list)
    calls: list[str] = field(default_factory=list)

    @dataclass
    class Reply:
        ok: bool
        text: str

    def start(self, threshold: float = 0.3) -> Any:
        self.calls.append("start")
        if self.live:
            return self.Reply(False, "The patrol is already running.")
        self.live.append("patrol1")
        return self.Reply(True, "Starting the patrol of 12 waypoints with 2 drones.")

    def stop(self) -> Any:
        self.calls.append("stop")
        self.live.clear()
        return self.Reply(True, "Stopping the patrol; the drones are flying home.")

    def running(self) -> list[str]:
        return list(self.live)


async def test_patrol_by_voice_whatever_this_drone_does() -> None:
    rig = Rig()
    central = FakeCentral()
    rig.dm.fleet = central
    res = await rig.dm.handle_utterance("start the patrol with all drones")  # landed: fine
    assert res.accepted and res.reply == "Starting the patrol of 12 waypoints with 2 drones."
    assert rig.dm.state is State.LANDED  # the fleet's drones fly, not this dialog's state
    res = await rig.dm.handle_utterance("stop the patrol")
    assert res.reply == "Stopping the patrol; the drones are flying home."
    assert central.calls == ["start", "stop"]
    res = await rig.dm.handle_utterance("stop the patrol")  # none running: this drone cancels
    assert res.reply == "OK, cancelled." and central.calls == ["start", "stop"]
    observer = await rig.dm.handle_utterance("start the patrol with all drones", role="observer")
    assert not observer.accepted and central.calls == ["start", "stop"]
    rig.dm.fleet = None
    res = await rig.dm.handle_utterance("start fleet patrol")
    assert res.reply == "There is no fleet manager here to run a patrol."
