"""The dialog manager with fakes that behave like the real ports, on a virtual clock."""

from __future__ import annotations

import json
from typing import Any

import pytest

from server.dialog.confirm import to_read_back
from server.dialog.manager import DialogManager, DialogParams
from server.dialog.states import State
from server.graph import Graph
from server.language.nlu import NLU
from server.settings import Settings, SettingsError
from tests.dialog.fakes import FakeDescriber, FakeFlight, FakeStore
from tests.supervisor.snaps import fake_flight_supervisor

NLU_ = NLU()


class Rig:
    def __init__(self, **flight: Any) -> None:
        self.graph = Graph()
        self.t = 0.0
        self.flight = FakeFlight(**flight)
        self.store = FakeStore()
        self.describer = FakeDescriber()
        self.replies: list[dict[str, Any]] = []
        self.states: list[dict[str, Any]] = []
        self.dm = DialogManager(
            self.graph,
            Settings(),
            self.flight,
            self.flight,
            self.describer,
            self.store,
            lambda: self.t,
            nlu=NLU_,
        )
        self.graph.subscribe("/console/reply", self.replies.append)
        self.graph.subscribe("/console/state", self.states.append)
        # the vehicle's safety monitors, whose alarms the dialog speaks
        self.supervisor = fake_flight_supervisor(self.flight)
        self.supervisor.on_alarm(self.dm.hear)

    def run(self, seconds: float, dt: float = 0.1) -> None:
        for _ in range(round(seconds / dt)):
            self.t = round(self.t + dt, 6)
            self.flight.step(self.t)
            self.dm.step(self.t)
            self.supervisor.step(self.t)


async def test_move_while_landed_is_refused_with_reason() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("go up 1 meter")
    assert not res.accepted
    assert res.reply == "I need to take off first."
    assert res.commands == [{"action": "move", "direction": "up", "distance": 1}]
    assert rig.flight.log == []
    assert rig.replies[-1]["level"] == "warn" and rig.replies[-1]["speak"] is True


async def test_compound_sentence_runs_in_order_and_confirms_values() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("take off, climb one meter and then fly to marker 3")
    assert res.accepted
    assert res.reply == "Taking off, then climbing 1 meter, then flying to marker 3."
    assert [e[1]["action"] for e in rig.flight.log] == ["takeoff", "move", "goto"]
    assert rig.dm.state is State.TAKING_OFF
    rig.run(2.2)
    assert rig.dm.state is State.EXECUTING
    rig.run(4.2)
    texts = [r["text"] for r in rig.replies]
    assert "Reached marker 3." in texts
    assert rig.dm.state is State.AIRBORNE_IDLE
    assert json.loads(rig.replies[0]["commands"])[2] == {"action": "goto", "marker": 3}


async def test_unknown_marker_is_refused() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.1)
    res = await rig.dm.handle_utterance("fly to marker 42")
    assert not res.accepted and res.reply == "There is no marker 42."


async def test_cancel_clears_the_queue() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.1)
    await rig.dm.handle_utterance("fly to marker 1 then marker 2 then marker 3")
    assert len(rig.flight.queue) == 3
    res = await rig.dm.handle_utterance("cancel that")
    assert res.accepted and res.reply == "OK, cancelled."
    assert rig.flight.queue == [] and rig.dm.state is State.AIRBORNE_IDLE


async def test_low_confidence_speech_asks_again_and_does_nothing() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("take off", confidence=0.2, source="speech")
    assert not res.accepted and "repeat" in res.reply
    assert rig.flight.log == []
    assert rig.store.rows[-1]["action"] == "asked_repeat"
    ok = await rig.dm.handle_utterance("take off", confidence=0.9, source="speech")
    assert ok.accepted


async def test_middling_confidence_speech_is_read_back_and_a_yes_runs_it() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("travel to point 7", confidence=0.4, source="speech")
    assert not res.accepted and rig.flight.log == []
    assert res.reply == (
        'Did you say "travel to point 7"? That is: flying to marker 7. '
        "Say yes to do it, or say the command again."
    )
    assert rig.store.rows[-1]["action"] == "asked_confirm"
    # The reply says it waits for a yes or a no (the console shows Yes / No buttons).
    assert res.expects == "confirm" and rig.replies[-1]["expects"] == "confirm"
    await rig.dm.handle_utterance("take off")
    rig.run(2.1)
    res = await rig.dm.handle_utterance("fly to marker 2", confidence=0.45, source="speech")
    assert not res.accepted and res.reply.startswith('Did you say "fly to marker 2"?')
    rig.t += 5.0
    res = await rig.dm.handle_utterance("Yes.", confidence=0.8, source="speech")
    assert res.accepted and res.reply == "Flying to marker 2."
    assert res.expects == "" and rig.replies[-1]["expects"] == ""
    assert rig.flight.log[-1][1] == {"action": "goto", "marker": 2}
    assert rig.store.rows[-1]["utterance"] == "Yes." and rig.store.rows[-1]["action"] == "executed"
    res = await rig.dm.handle_utterance("yes", confidence=0.9, source="speech")
    assert not res.accepted  # nothing is asked any more: a second yes runs nothing
    assert rig.flight.log[-1][1] == {"action": "goto", "marker": 2} and len(rig.flight.queue) <= 1


@pytest.mark.parametrize(
    ("answer", "confidence", "then"),
    [
        ("no", 0.9, "OK, I will not do that."),
        ("nope", 0.9, "OK, I will not do that."),
        ("yes", 0.2, None),  # the yes itself not heard well: asked again, question kept
    ],
)
async def test_a_question_that_is_not_confirmed_runs_nothing(
    answer: str, confidence: float, then: str | None
) -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off", confidence=0.35, source="speech")
    res = await rig.dm.handle_utterance(answer, confidence=confidence, source="speech")
    assert not res.accepted and rig.flight.log == []
    if then is not None:
        assert res.reply == then
        res = await rig.dm.handle_utterance("yes", confidence=0.9, source="speech")
        assert not res.accepted and rig.flight.log == []
    else:
        assert "repeat" in res.reply and res.expects == "confirm"  # the buttons stay
        res = await rig.dm.handle_utterance("yes", confidence=0.9, source="speech")
        assert res.accepted and rig.flight.log[-1][1] == {"action": "takeoff"}


@pytest.mark.parametrize(
    ("sentence", "confidence", "offered"),
    [
        ("take off", 0.3, True),  # the floor itself is read back
        ("take off", 0.49, True),
        ("take off", 0.5, False),  # at the threshold it is flown, not asked
        ("take off", 0.29, False),  # under the floor: "please repeat"
        ("take off and dance", 0.4, False),  # not understood whole
        ("", 0.4, False),
    ],
)
def test_what_is_read_back(sentence: str, confidence: float, offered: bool) -> None:
    interp = to_read_back(NLU_, sentence, confidence, threshold=0.5, floor=0.3)
    assert (interp is not None) is offered
    if interp is not None:
        assert interp.commands == [{"action": "takeoff"}]


async def test_the_console_answer_buttons_send_yes_and_no() -> None:
    """The page's Yes / No buttons send "yes" / "no" with source "button" (web/static/js/
    dialog.js): confident text, audited as the button's."""
    rig = Rig()
    await rig.dm.handle_utterance("take off", confidence=0.4, source="speech")
    res = await rig.dm.handle_utterance("no", source="button")
    assert res.reply == "OK, I will not do that." and res.expects == ""
    await rig.dm.handle_utterance("take off", confidence=0.4, source="speech")
    res = await rig.dm.handle_utterance("yes", source="button")
    assert res.accepted and rig.flight.log[-1][1] == {"action": "takeoff"}
    assert rig.store.rows[-1]["source"] == "button" and rig.store.rows[-1]["action"] == "executed"


async def test_a_yes_may_name_its_drone() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("uav1, take off", confidence=0.4, source="speech")
    assert res.reply.startswith('uav1: Did you say "take off"?')
    res = await rig.dm.handle_utterance("uav1, yes", confidence=0.9, source="speech")
    assert res.accepted and rig.flight.log[-1][1] == {"action": "takeoff"}


async def test_an_old_question_another_sentence_or_a_button_drops_it() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off", confidence=0.4, source="speech")
    rig.t += 15.1  # older than confirm.MAX_AGE_S
    res = await rig.dm.handle_utterance("yes", confidence=0.9, source="speech")
    assert not res.accepted and rig.flight.log == []
    assert res.reply == "That question has expired. Please say the command again."
    await rig.dm.handle_utterance("take off", confidence=0.4, source="speech")
    res = await rig.dm.handle_utterance("how much battery is left")
    res = await rig.dm.handle_utterance("yes")
    assert not res.accepted and rig.flight.log == []
    await rig.dm.handle_utterance("take off", confidence=0.4, source="speech")
    rig.dm.note_direct("land")  # the operator pressed a button meanwhile
    res = await rig.dm.handle_utterance("yes")
    assert not res.accepted and rig.flight.log == []
    assert res.reply == "No question is waiting for an answer. Please say the command itself."
    assert (await rig.dm.handle_utterance("no")).reply == res.reply


async def test_only_whole_understood_speech_is_read_back_and_observers_cannot_confirm() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("take off and dance", confidence=0.4, source="speech")
    assert "repeat" in res.reply  # part of it not understood: nothing to read back
    await rig.dm.handle_utterance("take off", confidence=0.4, source="speech")
    res = await rig.dm.handle_utterance("yes", role="observer")
    assert not res.accepted and rig.flight.log == []


def test_confirm_floor_is_a_setting() -> None:
    assert DialogParams.from_settings(Settings(confirm_floor=0.5)).confirm_floor == 0.5
    assert Settings.from_env({"UAVC_CONFIRM_FLOOR": "0.4"}).confirm_floor == 0.4
    for bad in (-0.1, 1.5):
        with pytest.raises(SettingsError, match="confirm_floor must be 0 to 1"):
            Settings(confirm_floor=bad)


async def test_queries_answer_with_numbers_and_describe() -> None:
    rig = Rig(battery_pct=76.0)
    res = await rig.dm.handle_utterance("how much battery is left")
    assert res.reply == "Battery is at 76 percent."
    res = await rig.dm.handle_utterance("what do you see")
    assert res.reply == "A room with a red marker on the wall." and rig.describer.calls == 1
    res = await rig.dm.handle_utterance("what's your altitude")
    assert res.reply == "I am on the ground."


async def test_not_understood_and_partly_understood() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("make me a sandwich")
    assert not res.accepted and res.commands == [] and "rephrase" in res.reply
    res = await rig.dm.handle_utterance("take off and do a barrel roll")
    assert not res.accepted and "do barrel roll" in res.reply
    assert rig.flight.log == []


async def test_observer_may_only_ask() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("take off", role="observer")
    assert not res.accepted and res.reply == "Only the pilot may command the drone."
    res = await rig.dm.handle_utterance("status", role="observer")
    assert res.accepted


async def test_emergency_and_leading_land_preempt() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.1)
    await rig.dm.handle_utterance("go to marker 1 then marker 2")
    await rig.dm.handle_utterance("land")
    assert rig.flight.log[-1] == ("preempt", {"action": "land"})
    assert rig.dm.state is State.LANDING
    res = await rig.dm.handle_utterance("emergency")
    assert res.accepted and rig.dm.state is State.EMERGENCY
    res = await rig.dm.handle_utterance("take off")
    assert not res.accepted and "emergency" in res.reply


async def test_audit_log_rows_and_state_topic() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off", role="pilot", source="rest")
    row = rig.store.rows[-1]
    assert row["utterance"] == "take off" and row["action"] == "executed"
    assert row["commands"] == [{"action": "takeoff"}] and row["role"] == "pilot"
    assert rig.states[-1]["state"] == "TAKING_OFF"
    assert "motion" in rig.states[-1]["grammars"]
    assert rig.graph.latched("/console/state")["state"] == "TAKING_OFF"


async def test_utterance_topic_and_interpret_service() -> None:
    rig = Rig()
    rig.graph.publish(
        "/console/utterance",
        {"text": "take off", "confidence": 0.95, "source": "speech", "drone": "uav1"},
    )
    for task in list(rig.dm._pending):
        await task
    assert rig.dm.state is State.TAKING_OFF
    rig.graph.publish(
        "/console/utterance", {"text": "land", "confidence": 1.0, "source": "text", "drone": "uav7"}
    )
    assert not rig.dm._pending  # another drone's utterance is ignored
    ans = await rig.graph.call_service(
        "/console/interpret", {"text": "go up 2 m", "state": "LANDED"}
    )
    assert ans == {"commands": []}
    ans = await rig.graph.call_service("/console/interpret", {"text": "go up 2 m"})
    assert ans == {"commands": [{"action": "move", "direction": "up", "distance": 2}]}


async def test_ans_battery_low_mid_task_alerts_and_returns_home() -> None:
    rig = Rig(battery_pct=27.0, drain_pct_per_s=0.5, task_s=10.0)
    await rig.dm.handle_utterance("take off and patrol markers 1, 2 and 3")
    rig.run(10.2)
    assert rig.dm.state is State.EXECUTING
    rig.run(5.0)
    warn = [r for r in rig.replies if r["level"] == "warn" and "Battery low" in r["text"]]
    assert len(warn) == 1 and "Returning home" in warn[0]["text"]
    assert ("preempt", {"action": "return_home"}) in rig.flight.log
    assert rig.dm.state is State.RETURNING
    assert rig.store.rows[-1]["role"] == "system"
    rig.flight.running = None
    rig.flight.queue.clear()
    rig.run(30.0)  # keeps draining to critical: land
    alerts = [r for r in rig.replies if r["level"] == "alert"]
    assert any("critical" in r["text"] for r in alerts)
    assert ("preempt", {"action": "land"}) in rig.flight.log


def test_params_from_settings() -> None:
    p = DialogParams.from_settings(Settings(confidence_threshold=0.7))
    assert p.confidence_threshold == 0.7 and p.battery_low_pct == Settings().battery_low_pct


@pytest.mark.parametrize("text", ["take off", "land", "stop"])
async def test_every_reply_is_logged(text: str) -> None:
    rig = Rig()
    await rig.dm.handle_utterance(text)
    # the intent before acting, the outcome after (issue 14)
    assert rig.store.rows[0]["action"] == "intent:utterance"
    assert len(rig.store.rows) == 2 and rig.store.rows[1]["outcome"] == rig.replies[-1]["text"]


def test_utterance_topic_without_a_loop_is_handled_at_once() -> None:
    """Lockstep: no event loop runs; an utterance published on the graph is handled in place."""
    rig = Rig()
    rig.graph.publish(
        "/console/utterance", {"text": "take off", "confidence": 0.2, "source": "speech"}
    )
    assert rig.replies[-1]["text"].startswith("Sorry, I am not sure")
    rig.graph.publish(
        "/console/utterance", {"text": "take off", "confidence": 0.8, "source": "speech"}
    )
    assert rig.dm.state is State.TAKING_OFF
    assert rig.replies[-1]["utterance"] == "take off"


async def test_state_follows_a_take_off_and_landing_made_outside_the_dialog() -> None:
    """A button or /ardrone/takeoff flies the drone without the dialog: "land" still works."""
    from dataclasses import replace

    rig = Rig()
    rig.flight.snap = replace(rig.flight.snap, flying=True, altitude_m=0.8)
    rig.run(0.5)
    assert rig.dm.state is State.AIRBORNE_IDLE
    res = await rig.dm.handle_utterance("land")
    assert res.accepted, res.reply
    rig.run(3.0)
    assert rig.dm.state is State.LANDED
    # and the other way: the drone landed by itself (e.g. its own low-battery landing)
    rig.flight.snap = replace(rig.flight.snap, flying=True)
    rig.run(0.5)
    rig.flight.snap = replace(rig.flight.snap, flying=False)
    rig.run(0.5)
    assert rig.dm.state is State.LANDED


async def test_a_sentence_is_checked_against_the_drone_of_now_not_the_last_period() -> None:
    """The drone landed a moment ago and no period has passed: "take off" is not refused
    with "I am already flying" (and, flying again, "land" is not "already on the ground")."""
    from dataclasses import replace

    rig = Rig()
    rig.flight.snap = replace(rig.flight.snap, flying=True, altitude_m=0.8)
    rig.run(0.5)
    assert rig.dm.state is State.AIRBORNE_IDLE
    rig.flight.snap = replace(rig.flight.snap, flying=False, altitude_m=0.0)
    res = await rig.dm.handle_utterance("take off")
    assert res.accepted, res.reply
    rig.run(3.0)
    rig.flight.snap = replace(rig.flight.snap, flying=False, altitude_m=0.0)
    rig.flight.queue.clear()
    rig.run(0.5)
    assert rig.dm.state is State.LANDED
    rig.flight.snap = replace(rig.flight.snap, flying=True, altitude_m=1.0)
    res = await rig.dm.handle_utterance("land")
    assert res.accepted, res.reply


async def test_a_stop_goes_to_a_drone_whose_state_the_dialog_cannot_know() -> None:
    """No fresh link (a console that has just adopted a vehicle): the dialog still believes
    "on the ground", but land, hover and emergency are sent for the vehicle to answer."""
    from dataclasses import replace

    rig = Rig()
    rig.flight.snap = replace(rig.flight.snap, link_ok=False)
    for said, action in (("land", "land"), ("hover", "hover"), ("emergency stop", "emergency")):
        rig.flight.log.clear()
        res = await rig.dm.handle_utterance(said)
        assert res.accepted, (said, res.reply)
        assert rig.flight.log == [("preempt", {"action": action})], said
    # with a fresh link the drone's own word stands: on the ground, "land" is refused
    rig.flight.snap = replace(rig.flight.snap, link_ok=True, flying=False, emergency=False)
    rig.dm.note_direct("reset")
    rig.run(0.5)
    rig.flight.log.clear()
    res = await rig.dm.handle_utterance("land")
    assert not res.accepted and res.reply == "I am already on the ground."
    assert rig.flight.log == []


async def test_no_alarms_before_the_drone_first_answers() -> None:
    from dataclasses import replace

    rig = Rig(battery_pct=0.0)
    rig.flight.snap = replace(rig.flight.snap, link_ok=False)
    rig.run(3.0)
    assert rig.replies == []
    rig.flight.battery_pct = 90.0
    rig.flight.snap = replace(rig.flight.snap, link_ok=True)
    rig.run(1.0)
    assert rig.replies == []
    rig.flight.snap = replace(rig.flight.snap, link_ok=False)
    rig.run(1.0)
    assert [r["level"] for r in rig.replies] == ["alert"]


async def test_a_spoken_emergency_heard_doubtfully_in_flight_hovers_and_asks() -> None:
    """An emergency cuts the motors: in flight a spoken one is honoured only when heard as one;
    heard doubtfully the drone hovers at once and the operator is asked."""
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.1)
    await rig.dm.handle_utterance("go to marker 1 then marker 2")
    res = await rig.dm.handle_utterance("Cut the motors.", confidence=0.4, source="speech")
    assert not res.accepted
    assert rig.flight.log[-1] == ("preempt", {"action": "hover"})
    assert ("preempt", {"action": "emergency"}) not in rig.flight.log
    assert res.reply.startswith('Hovering. Did you say "cut motors"?'), res.reply
    assert "cuts the motors" in res.reply
    assert res.commands == [{"action": "emergency"}]
    assert res.expects == "confirm" and rig.store.rows[-1]["action"] == "hovered_asked"
    res = await rig.dm.handle_utterance("Yes.", confidence=0.9, source="speech")
    assert ("preempt", {"action": "emergency"}) in rig.flight.log
    assert rig.dm.state is State.EMERGENCY


@pytest.mark.parametrize("confidence", [0.05, 0.35, 0.55])
async def test_an_emergency_under_its_bar_in_flight_hovers_whatever_the_confidence(
    confidence: float,
) -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.1)
    res = await rig.dm.handle_utterance("emergency", confidence=confidence, source="speech")
    assert rig.flight.log[-1] == ("preempt", {"action": "hover"})
    assert not res.accepted and "Did you say" in res.reply
    res = await rig.dm.handle_utterance("no", source="speech", confidence=0.9)
    assert ("preempt", {"action": "emergency"}) not in rig.flight.log


async def test_an_emergency_heard_as_one_cuts_the_motors_at_once() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.1)
    res = await rig.dm.handle_utterance("Kill the motors!", confidence=0.78, source="speech")
    assert res.accepted and rig.flight.log[-1] == ("preempt", {"action": "emergency"})
    # Typed, or from a button, an emergency is never questioned.
    rig2 = Rig()
    await rig2.dm.handle_utterance("take off")
    rig2.run(2.1)
    res = await rig2.dm.handle_utterance("emergency", confidence=0.1, source="text")
    assert res.accepted and rig2.flight.log[-1] == ("preempt", {"action": "emergency"})


async def test_a_doubtful_emergency_on_the_ground_does_not_hover() -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance("emergency", confidence=0.4, source="speech")
    assert not res.accepted and res.reply.startswith('Did you say "emergency"?')
    assert rig.flight.log == []
