"""Issue 18 in the dialog: refusals said before anything runs, help, "Did you mean", addressing,
filled-in turns and patrols, and marker ids in descriptions from the detector."""

from __future__ import annotations

import asyncio
from dataclasses import replace

import pytest

from drone.preflight import EMERGENCY_DOWN, DroneFacts, refusal
from server.captioner.grounding import SeenMarker, bearing_deg, ground_marker_ids
from server.dialog import assist
from server.dialog.addressing import Address, parse_address, recipients
from server.dialog.defaults import fill_defaults
from server.dialog.states import State
from tests.dialog.test_manager import NLU_, Rig

OK = DroneFacts(emergency=False, battery_pct=80.0, link_ok=True, flying=False)


# ---- preflight ----------------------------------------------------------------------------
def test_takeoff_refusals_name_the_way_out() -> None:
    assert refusal("takeoff", OK, 25.0) is None
    em = refusal("takeoff", replace(OK, emergency=True), 25.0)
    assert em is not None and "emergency" in em and "Reset" in em
    low = refusal("takeoff", replace(OK, battery_pct=11.0), 25.0)
    assert low is not None and "11 %" in low and "25 %" in low and "battery" in low
    link = refusal("takeoff", replace(OK, link_ok=False), 25.0)
    assert link is not None and "no link" in link
    # A reset while flying would toggle the emergency bit and cut the motors: refused.
    assert refusal("reset", replace(OK, flying=True), 25.0) is not None
    for stop in ("land", "emergency", "hover"):
        assert (
            refusal(stop, replace(OK, emergency=True, link_ok=False, battery_pct=1.0), 25) is None
        )


# ---- dialog flows -------------------------------------------------------------------------
async def test_typed_take_off_in_emergency_is_refused_before_anything_is_said() -> None:
    rig = Rig()
    rig.flight.snap = replace(rig.flight.snap, emergency=True)
    rig.run(0.6)
    assert rig.dm.state is State.EMERGENCY  # followed the drone's emergency bit
    res = await rig.dm.handle_utterance("take off")
    assert not res.accepted
    assert "Taking off" not in res.reply and "Reset" in res.reply
    assert all("Taking off" not in r["text"] for r in rig.replies)
    assert not any(kind == "submit" for kind, _ in rig.flight.log)
    # Reset (the drone's bit clears): the dialog is back on the ground and takes off.
    rig.flight.snap = replace(rig.flight.snap, emergency=False)
    rig.run(0.6)
    assert rig.dm.state is State.LANDED
    assert (await rig.dm.handle_utterance("take off")).accepted


async def test_take_off_at_low_battery_is_refused_with_the_numbers() -> None:
    rig = Rig(battery_pct=11.0)
    res = await rig.dm.handle_utterance("take off")
    assert not res.accepted and "11 %" in res.reply and rig.flight.log == []


async def test_after_a_stop_the_reply_says_reset_is_needed() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.5)
    await rig.dm.handle_utterance("emergency stop")
    rig.flight._emit("landed", {"action": "emergency"})
    assert rig.replies[-1]["text"] == EMERGENCY_DOWN and "Reset" in EMERGENCY_DOWN
    assert all(r["text"] != "Landed." for r in rig.replies)


async def test_direct_buttons_move_the_dialog_at_once() -> None:
    rig = Rig()
    rig.dm.note_direct("emergency")
    assert rig.dm.state is State.EMERGENCY
    assert not (await rig.dm.handle_utterance("take off")).accepted
    rig.dm.note_direct("reset")
    assert rig.dm.state is State.LANDED


async def test_help_gives_examples_for_the_state() -> None:
    rig = Rig()
    ground = await rig.dm.handle_utterance("help")
    assert ground.accepted and "take off" in ground.reply
    await rig.dm.handle_utterance("take off")
    rig.run(2.5)
    flying = await rig.dm.handle_utterance("what can you do?")
    assert "go to marker 3" in flying.reply and "land" in flying.reply
    rig.dm.note_direct("emergency")
    assert "Reset" in (await rig.dm.handle_utterance("help")).reply


@pytest.mark.parametrize("state", list(State))
def test_every_help_example_is_understood(state: State) -> None:
    examples = [
        s
        for s in assist.SUGGESTIONS
        if f"“{s}”" in assist.help_text(state) or state is State.LANDED
    ]
    for text in examples:
        assert NLU_.interpret(text), text


@pytest.mark.parametrize(
    ("said", "meant"),
    [
        ("take of", "take off"),
        ("fly to marcer 3", "go to marker 3"),
        ("lnad", "land"),
        ("turn arround", "turn around"),
    ],
)
async def test_not_understood_offers_the_closest_command(said: str, meant: str) -> None:
    rig = Rig()
    res = await rig.dm.handle_utterance(said)
    assert not res.accepted and f"Did you mean “{meant}”" in res.reply
    assert "None" not in res.reply and "'" not in res.reply  # no internal messages


async def test_nonsense_gets_no_guess() -> None:
    res = await Rig().dm.handle_utterance("make me a sandwich")
    assert "Did you mean" not in res.reply and "help" in res.reply


async def test_turn_around_rotate_and_patrol_all_are_filled_in() -> None:
    rig = Rig()
    await rig.dm.handle_utterance("take off")
    rig.run(2.5)
    res = await rig.dm.handle_utterance("turn around")
    assert res.accepted and res.reply == "Turning left 180 degrees."
    res = await rig.dm.handle_utterance("rotate 90")
    assert res.accepted and res.reply == "Turning left 90 degrees."
    res = await rig.dm.handle_utterance("patrol all markers")
    assert res.accepted and res.reply == "Patrolling markers 1, 2, 3, 4 and 5."
    assert res.commands[-1] == {"action": "patrol", "markers": [1, 2, 3, 4, 5]}
    res = await rig.dm.handle_utterance("come back")
    assert res.accepted and "land" in res.reply


def test_fill_defaults_leaves_stated_slots() -> None:
    cmds = [
        {"action": "turn", "direction": "right", "angle": 30},
        {"action": "patrol", "markers": [2]},
    ]
    assert fill_defaults(cmds, [1, 2]) == cmds


# ---- addressing ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "names", "everyone", "rest"),
    [
        ("uav2 take off", ("uav2",), False, "take off"),
        ("drone 2, fly to marker 3", ("uav2",), False, "fly to marker 3"),
        ("Drone two: land", ("uav2",), False, "land"),
        ("all drones land", None, True, "land"),
        ("everyone, come back", None, True, "come back"),
        ("take off", None, False, "take off"),
        ("drone 2", None, False, "drone 2"),  # only an address: nothing to do
    ],
)
def test_parse_address(text: str, names: tuple[str, ...] | None, everyone: bool, rest: str) -> None:
    a = parse_address(text)
    assert (a.names, a.everyone, a.text) == (names, everyone, rest)


def test_recipients() -> None:
    fleet = ["uav1", "uav2", "uav3"]
    assert recipients(parse_address("uav2 land"), "uav1", fleet) == ["uav2"]
    assert recipients(parse_address("all drones land"), "uav1", fleet) == fleet
    assert recipients(parse_address("land"), "uav3", fleet) == ["uav3"]
    assert recipients(parse_address("uav7 land"), "uav1", fleet) == []
    assert Address("land").includes("uav1") is False


async def test_addressed_utterances_reach_only_their_drone() -> None:
    rig = Rig()
    rig.dm.drones = lambda: ["uav1", "uav2"]
    rig.graph.publish("/console/utterance", {"text": "uav2 take off", "drone": "uav1"})
    assert rig.replies == []  # for uav2, not this drone (uav1)
    rig.graph.publish("/console/utterance", {"text": "uav5 land", "drone": "uav1"})
    assert rig.replies[-1]["text"] == "There is no drone uav5. Drones here: uav1, uav2."
    res = await rig.dm.handle_utterance("uav1, take off")
    assert res.accepted and res.reply == "uav1: Taking off."


async def test_a_bare_answer_goes_to_the_drone_that_asked() -> None:
    """The console names the drone whose "Did you say …?" is open (``asked_by``) when another
    drone is selected: only the asker takes a bare yes or no; other sentences, and answers
    that name their drone, are routed as usual."""

    async def say(rig: Rig, msg: dict[str, object]) -> None:
        rig.graph.publish("/console/utterance", {"confidence": 0.9, "source": "speech", **msg})
        while rig.dm._pending:
            await asyncio.gather(*rig.dm._pending)

    asker = Rig()  # uav1 asked; the console has uav2 selected
    asker.dm.drones = lambda: ["uav1", "uav2"]
    await asker.dm.handle_utterance("take off", confidence=0.4, source="speech")
    await say(asker, {"text": "Yes.", "drone": "uav2", "asked_by": "uav1"})
    assert asker.flight.log[-1][1] == {"action": "takeoff"}
    assert asker.replies[-1]["text"] == "Taking off."

    other = Rig()  # this drone (uav1) is selected but uav2 asked: the yes is not for it
    other.dm.drones = lambda: ["uav1", "uav2"]
    n = len(other.replies)
    await say(other, {"text": "yes", "drone": "uav1", "asked_by": "uav2"})
    assert len(other.replies) == n and other.flight.log == []
    await say(other, {"text": "take off", "drone": "uav1", "asked_by": "uav2"})  # not an answer
    assert other.flight.log[-1][1] == {"action": "takeoff"}
    await say(other, {"text": "uav1, yes", "drone": "uav1", "asked_by": "uav2"})  # named: its own
    assert other.replies[-1]["text"].startswith("uav1: No question is waiting")
    await say(other, {"text": "no", "drone": "uav1", "asked_by": "uav9"})  # no such drone
    assert other.replies[-1]["text"].startswith("No question is waiting")


# ---- scene descriptions -------------------------------------------------------------------
def test_marker_ids_come_from_the_detector() -> None:
    seen = [SeenMarker(3, bearing_deg(0.0, 0.0, 0.0, 2.0, 0.1))]
    assert seen[0].side == "ahead"
    assert ground_marker_ids("marker 0 far ahead and a red chair close on the left", seen) == (
        "marker 3 far ahead and a red chair close on the left"
    )
    two = [SeenMarker(4, -40.0), SeenMarker(7, 40.0)]
    assert ground_marker_ids("marker 0 close on the left , marker 1 far on the right", two) == (
        "marker 7 close on the left , marker 4 far on the right"
    )
    assert ground_marker_ids("marker 5 close ahead", []) == "a marker close ahead"
    assert ground_marker_ids("a chair close ahead", [SeenMarker(2, 0.0)]) == (
        "a chair close ahead. Marker 2 in view."
    )


async def test_ans_alarms_name_their_monitor_on_the_reply() -> None:
    rig = Rig()
    assert (await rig.dm.handle_utterance("take off")).accepted
    rig.run(2.5)
    rig.flight.battery_pct = 20.0
    rig.run(1.5)
    alarms = [r for r in rig.replies if r["alarm"]]
    assert alarms and alarms[0]["alarm"] == "battery" and alarms[0]["drone"] == "uav1"


async def test_task_manager_messages_reach_the_operator_in_plain_words() -> None:
    assert assist.operator_words("turn angle must be in (0, 720] degrees, got 1000.0") == (
        "I can turn by up to 720 degrees at a time; you asked for 1000."
    )
    plain = assist.operator_words("'turn' needs 'direction' left or right; got None")
    assert "None" not in plain and "“turn left 90 degrees”" in plain
    assert assist.operator_words("There is no marker 9.") == "There is no marker 9."


def test_no_takeoff_while_the_navdata_is_doubted() -> None:
    why = refusal("takeoff", replace(OK, navdata_doubt="packets off the numbering"), 25.0)
    assert why is not None and "inconsistent" in why and "packets off the numbering" in why
    for stop in ("land", "hover", "emergency"):
        assert refusal(stop, replace(OK, navdata_doubt="x", flying=True), 25.0) is None
