"""The NLU against DESIGN §4: every rule, mappings, numbers, units, compounds, nonsense."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.language.errors import UnknownStateError
from server.language.nlu import MAX_RUN_WORDS, MAX_UTTERANCE_CHARS, NLU
from server.language.numbers import words_to_numbers

DATA = Path(__file__).resolve().parent.parent / "data" / "nlu_labelled.jsonl"


@pytest.fixture(scope="module")
def nlu() -> NLU:
    return NLU()


def one(nlu: NLU, text: str) -> dict:
    cmds = nlu.interpret(text)
    assert len(cmds) == 1, (text, cmds)
    return cmds[0]


# One utterance per rule of rules.xml (rule id -> example, expected command).
RULE_EXAMPLES = {
    "emergency": ("kill the motors", {"action": "emergency"}),
    "hover": ("hold position", {"action": "hover"}),
    "land": ("touch down", {"action": "land"}),
    "takeoff": ("lift off", {"action": "takeoff"}),
    "return_home.verb_place": ("fly back to the launch point", {"action": "return_home"}),
    "return_home.short": ("come back", {"action": "return_home"}),
    "cancel": ("never mind", {"action": "cancel"}),
    "query.battery": ("how much battery is left", {"action": "query", "item": "battery"}),
    "query.altitude": ("how high are you", {"action": "query", "item": "altitude"}),
    "query.position": ("where are you", {"action": "query", "item": "position"}),
    "query.state": ("what are you doing", {"action": "query", "item": "state"}),
    "describe": ("what do you see", {"action": "describe"}),
    "help": ("what can you do?", {"action": "help"}),
    "goto.marker": ("navigate to the marker number 7", {"action": "goto", "marker": 7}),
    "goto.ordinal": ("go to the third tag", {"action": "goto", "marker": 3}),
    "goto.number": ("fly to 4", {"action": "goto", "marker": 4}),
    "goto.waypoint": ("fly to waypoint 3", {"action": "goto", "waypoint": 3}),
    "patrol.waypoints": (
        "patrol waypoints 1, 2, 3 and 4",
        {"action": "patrol", "waypoints": [1, 2, 3, 4]},
    ),
    "patrol.waypoint_range": (
        "patrol waypoints 1 to 4",
        {"action": "patrol", "waypoints": [1, 2, 3, 4]},
    ),
    "patrol.list": ("patrol markers 1, 3 and 5", {"action": "patrol", "markers": [1, 3, 5]}),
    "patrol.range": ("patrol markers 2 through 5", {"action": "patrol", "markers": [2, 3, 4, 5]}),
    "patrol.markers_first": ("markers 4 and 2 on patrol", {"action": "patrol", "markers": [4, 2]}),
    "turn.around": ("turn around", {"action": "turn", "angle": 180}),
    "turn.side_angle": ("yaw right 45", {"action": "turn", "direction": "right", "angle": 45}),
    "turn.angle_side": (
        "rotate 30 degrees left",
        {"action": "turn", "direction": "left", "angle": 30},
    ),
    "turn.angle": ("rotate 90 degrees", {"action": "turn", "angle": 90}),
    "turn.maneuver": (
        "make a 90 degree turn to the right",
        {"action": "turn", "direction": "right", "angle": 90},
    ),
    "turn.do_number": ("do a 360", {"action": "turn", "angle": 360}),
    "turn.bare": ("clockwise 90 degrees", {"action": "turn", "direction": "right", "angle": 90}),
    "move.up_verb": (
        "rise by half a metre",
        {"action": "move", "direction": "up", "distance": 0.5},
    ),
    "move.down_verb": ("descend 20 cm", {"action": "move", "direction": "down", "distance": 0.2}),
    "move.forward_verb": (
        "advance 2 meters",
        {"action": "move", "direction": "forward", "distance": 2},
    ),
    "move.back_verb": ("back up", {"action": "move", "direction": "backward"}),
    "move.dir_dist": (
        "strafe left 50 cm",
        {"action": "move", "direction": "left", "distance": 0.5},
    ),
    "move.dist_dir": (
        "move three feet to the right",
        {"action": "move", "direction": "right", "distance": 0.9144},
    ),
    # issue 13 items 6, 7, 9: fleet patrol, objects, answers, tag search
    "patrol_start.fleet": ("start the patrol with all drones", {"action": "patrol_start"}),
    "patrol_stop.fleet": ("stop the patrol", {"action": "patrol_stop"}),
    # a paused patrol (server/fleet/states.py)
    "patrol_resume.fleet": ("resume the patrol", {"action": "patrol_resume"}),
    "patrol_pause.fleet": ("pause the patrol", {"action": "patrol_pause"}),
    "search.markers": ("look for a tag", {"action": "search"}),
    "goto.object": (
        "fly to the red chair",
        {"action": "goto", "object": "chair", "colour": "red"},
    ),
    "face.object": (
        "face the north window",
        {"action": "turn", "object": "window", "which": "north"},
    ),
    "goto.unknown_object": ("go to the fridge", {"action": "goto", "object": "fridge"}),
    "choose.answer": ("the blue one", {"action": "choose", "colour": "blue"}),
}


def test_every_rule_has_an_example(nlu: NLU) -> None:
    assert {r.id for r in nlu.grammar.rules} == set(RULE_EXAMPLES)


@pytest.mark.parametrize("rule_id", sorted(RULE_EXAMPLES))
def test_rule(nlu: NLU, rule_id: str) -> None:
    text, expected = RULE_EXAMPLES[rule_id]
    parsed = nlu.parse(text).parsed
    assert [p.command for p in parsed] == [expected]
    assert parsed[0].rule == rule_id


@pytest.mark.parametrize(
    ("word", "label"),
    [
        ("roof", "up"),
        ("ceiling", "up"),
        ("above", "up"),
        ("floor", "down"),
        ("ahead", "forward"),
        ("rear", "backward"),
        ("starboard", "right"),
        ("port", "left"),
    ],
)
def test_direction_mapping(nlu: NLU, word: str, label: str) -> None:
    assert one(nlu, f"go {word} 1 meter") == {"action": "move", "direction": label, "distance": 1}


@pytest.mark.parametrize(
    ("word", "label"),
    [
        ("clockwise", "right"),
        ("counter-clockwise", "left"),
        ("anticlockwise", "left"),
        ("left", "left"),
    ],
)
def test_rotation_mapping(nlu: NLU, word: str, label: str) -> None:
    assert one(nlu, f"rotate {word}") == {"action": "turn", "direction": label}


def test_every_set_word_is_understood_in_a_rule(nlu: NLU) -> None:
    """Each word of the main sets, put into a sentence that uses the set, is understood."""
    g = nlu.grammar
    for word, label in g.sets["DIRECTION"].labels.items():
        assert one(nlu, f"move {word} 2 meters")["direction"] == label, word
    for word, label in g.sets["SIDE"].labels.items():
        assert one(nlu, f"turn {word} 10 degrees")["direction"] == label, word
    for word in g.sets["MARKER"].labels:
        assert one(nlu, f"go to {word} 3") == {"action": "goto", "marker": 3}, word
    for word, label in g.sets["ORDINAL"].labels.items():
        assert one(nlu, f"go to the {word} marker") == {"action": "goto", "marker": int(label)}, (
            word
        )
    for word, factor in g.sets["DIST_UNIT"].values.items():
        got = one(nlu, f"go up 2 {word}")["distance"]
        assert got == pytest.approx(2 * factor), word
    for word in g.sets["UP_VERB"].labels:
        assert one(nlu, f"{word} 1 meter") == {
            "action": "move",
            "direction": "up",
            "distance": 1,
        }, word
    for word in g.sets["DOWN_VERB"].labels:
        assert one(nlu, f"{word} 1 meter") == {
            "action": "move",
            "direction": "down",
            "distance": 1,
        }, word
    for word in g.sets["TURN_VERB"].labels:
        assert one(nlu, f"{word} left 20 degrees") == {
            "action": "turn",
            "direction": "left",
            "angle": 20,
        }, word
    for word in g.sets["PATROL_VERB"].labels:
        assert one(nlu, f"{word} markers 1 and 2") == {"action": "patrol", "markers": [1, 2]}, word


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("twenty five", "25"),
        ("a hundred and eighty", "180"),
        ("one and a half", "1.5"),
        ("half a", "0.5"),
        ("three point five", "3.5"),
        ("one eighty", "180"),
        ("one three five", "1 3 5"),
        ("two thousand and twelve", "2012"),
        ("a quarter", "0.25"),
        ("three quarters of a", "0.75"),
        ("2 and a half", "2.5"),
        ("no numbers here", "no numbers here"),
        ("ninety nine", "99"),
        ("twelve", "12"),
        ("zero point two five", "0.25"),
    ],
)
def test_numbers(text: str, expected: str) -> None:
    assert words_to_numbers(text) == expected


@pytest.mark.parametrize(
    ("text", "distance"),
    [
        ("go up 2 metres", 2),
        ("go up 50 cm", 0.5),
        ("go up 3 feet", 0.9144),
        ("go up 1 foot", 0.3048),
        ("go up 6 inches", 0.1524),
        ("go up 2m", 2),
        ("go up 25cm", 0.25),
        ("go up 1.5 meters", 1.5),
        ("go up one and a half meters", 1.5),
        ("go up half a meter", 0.5),
        ("go up a meter", 1),
        ("go up 2", 2),
        ("go up twenty five centimeters", 0.25),
    ],
)
def test_units_to_metres(nlu: NLU, text: str, distance: float) -> None:
    assert one(nlu, text)["distance"] == pytest.approx(distance)


def test_degrees_and_radians(nlu: NLU) -> None:
    assert one(nlu, "turn left 90°")["angle"] == 90
    assert one(nlu, "turn left 1 radian")["angle"] == pytest.approx(57.29578, abs=1e-4)


def test_omitted_slots_are_omitted(nlu: NLU) -> None:
    assert nlu.interpret("go up") == [{"action": "move", "direction": "up"}]
    assert nlu.interpret("patrol") == [{"action": "patrol"}]
    assert nlu.interpret("turn around") == [{"action": "turn", "angle": 180}]


def test_types(nlu: NLU) -> None:
    cmd = one(nlu, "fly to marker five")
    assert isinstance(cmd["marker"], int)
    patrol = one(nlu, "patrol markers one, three and five")
    assert patrol["markers"] == [1, 3, 5] and all(isinstance(m, int) for m in patrol["markers"])


def test_compound_sentences_keep_spoken_order(nlu: NLU) -> None:
    assert nlu.interpret("take off, climb one meter and then fly to marker 3") == [
        {"action": "takeoff"},
        {"action": "move", "direction": "up", "distance": 1},
        {"action": "goto", "marker": 3},
    ]
    assert nlu.interpret("take off and go to marker 2 then land") == [
        {"action": "takeoff"},
        {"action": "goto", "marker": 2},
        {"action": "land"},
    ]
    # "and" inside a patrol list does not split it
    assert nlu.interpret("patrol between 2 and 4 and then land") == [
        {"action": "patrol", "markers": [2, 4]},
        {"action": "land"},
    ]


def test_fillers_and_punctuation(nlu: NLU) -> None:
    assert nlu.interpret("Uh, drone, PLEASE take off!!") == [{"action": "takeoff"}]
    assert nlu.interpret("um... could you land now?") == [{"action": "land"}]


@pytest.mark.parametrize(
    "text",
    [
        "",
        "   ",
        "hello there",
        "make me a sandwich",
        "go",
        "turn",
        "fly to marker",
        "42",
        "climb to 2 meters",
        "the quick brown fox",
        "please",
        "open the pod bay doors",
        "x" * (MAX_UTTERANCE_CHARS + 1),
    ],
)
def test_nonsense_gives_nothing(nlu: NLU, text: str) -> None:
    assert nlu.interpret(text) == []


def test_partly_understood_reports_the_rest(nlu: NLU) -> None:
    interp = nlu.parse("take off and do a barrel roll")
    assert interp.commands == [{"action": "takeoff"}]
    assert interp.unparsed == ("do barrel roll",)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # Speech recognisers often write no separator between commands said back to back.
        ("Land take off.", [{"action": "land"}, {"action": "takeoff"}]),
        ("take off hover", [{"action": "takeoff"}, {"action": "hover"}]),
        (
            "take off and hover land",
            [{"action": "takeoff"}, {"action": "hover"}, {"action": "land"}],
        ),
        (
            "take off fly forward two meters turn left",
            [
                {"action": "takeoff"},
                {"action": "move", "direction": "forward", "distance": 2},
                {"action": "turn", "direction": "left"},
            ],
        ),
        (
            "land take off and fly to marker 3",
            [{"action": "land"}, {"action": "takeoff"}, {"action": "goto", "marker": 3}],
        ),
    ],
)
def test_commands_said_back_to_back(nlu: NLU, text: str, expected: list[dict]) -> None:
    assert nlu.interpret(text) == expected


@pytest.mark.parametrize(
    "text",
    [
        "fly forward 2 meters left",  # "2 meters left" is no command of its own
        "go up down",  # a lone "down" belongs to its neighbour
        "land up",
        "help me what you see",  # questions and dialog commands are not run together
        "land land land land",  # more than MAX_RUN_COMMANDS
        "take off land hover land",
    ],
)
def test_runs_that_are_not_split(nlu: NLU, text: str) -> None:
    interp = nlu.parse(text)
    assert interp.commands == []
    assert interp.unparsed == (nlu.normalise(text).strip(" ,"),)


def test_a_run_of_too_many_words_is_not_split(nlu: NLU) -> None:
    # The splits tried grow with the square of the words: a clause is split only up to
    # MAX_RUN_WORDS words.
    assert nlu.interpret("patrol markers 1 2 3 4 land") == [
        {"action": "patrol", "markers": [1, 2, 3, 4]},
        {"action": "land"},
    ]
    markers = " ".join(str(i) for i in range(1, MAX_RUN_WORDS))
    assert nlu.interpret(f"patrol markers {markers} land") == []


@pytest.mark.parametrize(
    ("text", "answer"),
    [
        ("Yes.", "yes"),
        ("yes please", "yes"),
        ("That's right!", "yes"),
        ("That\u2019s right", "yes"),  # a phone keyboard's curly apostrophe
        ("affirmative", "yes"),
        ("No.", "no"),
        ("nope", "no"),
        ("yes, take off", None),  # a command, not an answer
        ("right", None),  # a direction, never taken for a yes
        ("", None),
        ("yes " * 400, None),
    ],
)
def test_answers(nlu: NLU, text: str, answer: str | None) -> None:
    assert nlu.answer(text) == answer


def test_an_answer_is_no_command(nlu: NLU) -> None:
    assert nlu.interpret("yes") == []
    assert nlu.interpret("yes, take off") == [{"action": "takeoff"}]


def test_per_state_grammars(nlu: NLU) -> None:
    assert nlu.interpret("go up 1 meter", state="LANDED") == []
    assert nlu.interpret("go up 1 meter", state="AIRBORNE_IDLE") == [
        {"action": "move", "direction": "up", "distance": 1}
    ]
    assert nlu.interpret("take off", state="AIRBORNE_IDLE") == []
    assert nlu.interpret("take off", state="LANDED") == [{"action": "takeoff"}]
    assert nlu.interpret("emergency", state="EMERGENCY") == [{"action": "emergency"}]
    assert "motion" not in nlu.active_grammars("LANDED")
    with pytest.raises(UnknownStateError) as err:
        nlu.interpret("land", state="FLOATING")
    assert isinstance(err.value, KeyError)


def test_labelled_set_accuracy(nlu: NLU) -> None:
    rows = [json.loads(line) for line in DATA.read_text().splitlines() if line.strip()]
    assert len(rows) >= 300
    wrong = [
        (r["text"], nlu.interpret(r["text"]), r["commands"])
        for r in rows
        if nlu.interpret(r["text"]) != r["commands"]
    ]
    assert 1 - len(wrong) / len(rows) >= 0.98, wrong[:10]


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=200))
def test_arbitrary_text_never_raises(text: str) -> None:
    cmds = _NLU.interpret(text)
    assert isinstance(cmds, list)
    json.dumps(cmds, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.sampled_from(
            [
                "take",
                "off",
                "go",
                "up",
                "marker",
                "3",
                "and",
                "then",
                "patrol",
                "1",
                ",",
                "half",
                "a",
                "meter",
                "turn",
                "left",
                "degrees",
                "one",
                "hundred",
                "twenty",
                "the",
                "please",
                "through",
                "99999999999999",
            ]
        ),
        max_size=30,
    )
)
def test_word_salad_never_raises(words: list[str]) -> None:
    cmds = _NLU.interpret(" ".join(words))
    json.dumps(cmds, allow_nan=False)
    for c in cmds:
        assert c["action"] in {
            "takeoff",
            "land",
            "hover",
            "emergency",
            "return_home",
            "describe",
            "cancel",
            "move",
            "turn",
            "goto",
            "patrol",
            "query",
            "search",
            "choose",
            "help",
            "patrol_start",
            "patrol_stop",
            "patrol_pause",
            "patrol_resume",
        }


_NLU = NLU()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Go up one meter and a half", [{"action": "move", "direction": "up", "distance": 1.5}]),
        ("fly up", [{"action": "move", "direction": "up"}]),
        ("stop everything", [{"action": "hover"}]),
        ("stop the motors", [{"action": "emergency"}]),
        ("descend to the ground", [{"action": "land"}]),
        ("move closer to marker 2", [{"action": "goto", "marker": 2}]),
        ("wait a second", [{"action": "hover"}]),
        ("what can you see right now", [{"action": "describe"}]),
        ("tell me what's in front of you", [{"action": "describe"}]),
        (
            "go to marker 3 and then to marker 4",
            [{"action": "goto", "marker": 3}, {"action": "goto", "marker": 4}],
        ),
        ("come down and land", [{"action": "land"}]),
        ("fly forward, 2 meters", [{"action": "move", "direction": "forward", "distance": 2}]),
        ("what are you doing right now", [{"action": "query", "item": "state"}]),
        ("go up 2 mm", [{"action": "move", "direction": "up", "distance": 0.002}]),
    ],
)
def test_phrasings_found_in_review(nlu: NLU, text: str, expected: list[dict]) -> None:
    assert nlu.interpret(text) == expected


@pytest.mark.parametrize(
    "text",
    [
        "go forward -5 meters",
        "go forward \u22125 meters",
        "fly left - 2 meters",
        "turn left -90 degrees",
        "go up -.5 meters",
        "take off and go forward -3 meters",
    ],
)
def test_a_signed_amount_is_never_flown_without_its_sign(text: str) -> None:
    # Issue 14: "go forward -5 meters" lost its sign and flew forward.
    commands = _NLU.interpret(text)
    assert all("distance" not in c and "angle" not in c for c in commands), commands
    assert "minus" in _NLU.normalise(text).split()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("patrol markers 1-3", [{"action": "patrol", "markers": [1, 3]}]),
        ("take-off", [{"action": "takeoff"}]),
    ],
)
def test_hyphens_that_are_not_signs_still_work(
    text: str, expected: list[dict[str, object]]
) -> None:
    assert _NLU.interpret(text) == expected


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("fly to waypoint 3", [{"action": "goto", "waypoint": 3}]),
        ("go to wp2", [{"action": "goto", "waypoint": 2}]),
        ("go to wp 2", [{"action": "goto", "waypoint": 2}]),
        ("please head to way point three", [{"action": "goto", "waypoint": 3}]),
        ("patrol waypoints 1 to 4", [{"action": "patrol", "waypoints": [1, 2, 3, 4]}]),
        ("patrol waypoints 4 through 2", [{"action": "patrol", "waypoints": [4, 3, 2]}]),
        ("patrol waypoints 1 and 3", [{"action": "patrol", "waypoints": [1, 3]}]),
        # markers keep their reading: "1 to 4" is the two markers
        ("patrol markers 1 to 4", [{"action": "patrol", "markers": [1, 4]}]),
        (
            "take off and fly to waypoint 3",
            [{"action": "takeoff"}, {"action": "goto", "waypoint": 3}],
        ),
    ],
)
def test_waypoints_by_voice(text: str, expected: list[dict[str, object]]) -> None:
    assert _NLU.interpret(text) == expected


def test_a_drone_named_before_a_waypoint_is_an_address() -> None:
    from server.dialog.addressing import parse_address

    for said in ("drone 2 fly to waypoint 3", "drone 2, fly to waypoint 3", "uav2 fly to wp 3"):
        address = parse_address(said)
        assert address.names == ("uav2",), said
        assert _NLU.interpret(address.text) == [{"action": "goto", "waypoint": 3}], said


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # Transcripts tiny.en wrote, word for word, for speech the grammars could not read.
        (
            "Hover for now and tell me your battery level.",
            [{"action": "hover"}, {"action": "query", "item": "battery"}],
        ),
        ("Hover for now.", [{"action": "hover"}]),
        ("Stay there for the moment.", [{"action": "hover"}]),
        ("Hold on for a second.", [{"action": "hover"}]),
        ("Hover for a bit.", [{"action": "hover"}]),
        ("Y'all left by thirty degrees.", [{"action": "turn", "direction": "left", "angle": 30}]),
        ("Yall right by 45 degrees.", [{"action": "turn", "direction": "right", "angle": 45}]),
        ("You all left by 30 degrees.", [{"action": "turn", "direction": "left", "angle": 30}]),
        ("Yaw left by 30 degrees.", [{"action": "turn", "direction": "left", "angle": 30}]),
        ("Yaw right.", [{"action": "turn", "direction": "right"}]),
    ],
)
def test_grammar_gaps_heard_in_speech(nlu: NLU, text: str, expected: list[dict]) -> None:
    parsed = nlu.parse(text)
    assert parsed.commands == expected and parsed.unparsed == (), parsed


@pytest.mark.parametrize("text", ["Slow down.", "slow down a little", "Slow down, please."])
def test_slow_down_is_not_a_descent(nlu: NLU, text: str) -> None:
    # "slow" is a filler word ("fly forward slowly"): "slow down" read "down", a move down.
    assert nlu.interpret(text) == []
