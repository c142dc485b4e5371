"""Speech never cuts the motors, nor flies the other way, on a guess (no model).

The transcripts are what tiny.en wrote for speech it was never tuned on (hibari-tts's neural
voice, espeak-ng): "yaw left by thirty degrees" heard "Y'all left by thirty degrees." was
snapped to "kill left by 30 degrees" (an emergency and a turn); "hover for now and tell me your
battery level", heard word for word, was snapped to "hover floor …" (a move down).
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.language.nlu import default_nlu
from server.speech.recognizer import choose
from server.speech.snap import Snapper, opposite
from server.speech.vocabulary import vocabulary

_NLU = default_nlu()
_SNAPPER = Snapper(_NLU, vocabulary(_NLU.grammar))
THRESHOLD = 0.5  # Settings().confidence_threshold
FLOOR = 0.3  # Settings().confirm_floor

# tiny.en's four beams for hibari's "yaw left by thirty degrees" at 130 words per minute.
YAW_BEAMS = [
    ("Y'all left by thirty degrees.", 0.91),
    ("Y'all left by 30 degrees.", 0.8),
    ("You are left by thirty degrees.", 0.68),
    ("Yall left by thirty degrees.", 0.6),
]
HOVER_BEAMS = [
    ("Hover for now and tell me your battery level.", 0.96),
    ("Hover for now, and tell me your battery level.", 0.84),
    ("Hover for now until me your battery level.", 0.73),
    ("Hover for now. And tell me your battery level.", 0.71),
]


def actions(commands: list[dict[str, Any]]) -> list[str]:
    return [str(c["action"]) for c in commands]


def test_the_yaw_that_was_snapped_to_kill_is_a_turn_and_no_emergency() -> None:
    rec = choose(YAW_BEAMS, _SNAPPER)
    assert "emergency" not in actions(rec.commands), rec
    assert rec.commands == [{"action": "turn", "direction": "left", "angle": 30}], rec
    assert rec.snap_distance == 0.0  # read as heard: the grammars know "y'all left"


@pytest.mark.parametrize(
    "heard",
    [
        "Yaul left by 30 degrees.",
        "Kyle left by 30 degrees.",
        "Gill.",
        "Skill the motors.",
        "Bill left.",
        "Cut the mother's.",
        "Kilt.",
    ],
)
def test_a_snap_never_introduces_an_emergency(heard: str) -> None:
    s = _SNAPPER.snap(heard)
    assert "emergency" not in actions(s.commands), s
    rec = choose([(heard, 0.95)], _SNAPPER)
    assert "emergency" not in actions(rec.commands), rec


def test_an_emergency_heard_as_one_is_kept() -> None:
    for heard in ("Kill the motors.", "Emergency!", "Kill the motors and uh banana."):
        s = _SNAPPER.snap(heard)
        assert actions(s.commands)[:1] == ["emergency"], s


WORDS = [
    "kill", "kil", "gill", "skill", "cut", "shut", "off", "motors", "mothers", "left", "right",
    "up", "down", "climb", "descend", "by", "30", "degrees", "yall", "land", "lend", "hover",
    "for", "now", "and", "the", "emergency", "emergence", "mayday", "made", "panic", "banana",
    "stop", "top",
]  # fmt: skip


@settings(max_examples=80, deadline=None, derandomize=True)
@given(st.lists(st.sampled_from(WORDS), min_size=1, max_size=6))
def test_no_snap_has_more_emergencies_than_the_transcript(words: list[str]) -> None:
    heard = " ".join(words)
    s = _SNAPPER.snap(heard)
    said = actions(_NLU.parse(heard).commands).count("emergency")
    assert actions(s.commands).count("emergency") <= said, (heard, s)


def test_hover_for_now_is_a_hover_and_a_battery_question() -> None:
    rec = choose(HOVER_BEAMS, _SNAPPER)
    assert rec.commands == [{"action": "hover"}, {"action": "query", "item": "battery"}], rec
    assert rec.snap_distance == 0.0
    bent = choose([("Hover for now and flurb.", 0.95)], _SNAPPER, cap=THRESHOLD - 0.01)
    assert bent.confidence < THRESHOLD  # "flurb" -> "floor", a move down: read back at most


@pytest.mark.parametrize(
    ("heard", "never"),
    [
        ("Ascend lower.", "down"),  # "ascend" was bent into "descend"
        ("Climb down.", "up"),  # "down" was bent into "ten": a 10 m climb
        ("Go left, uh, flurb.", "right"),
        ("Fly rearward, blah.", "forward"),
    ],
)
def test_a_snap_never_turns_a_direction_into_its_opposite(heard: str, never: str) -> None:
    s = _SNAPPER.snap(heard)
    directions = [c.get("direction") for c in s.commands]
    assert never not in directions, s


def test_opposites() -> None:
    assert opposite("up") == "down" and opposite("left") == "right"
    assert opposite("forward") == "backward" and opposite("backward") == "forward"
    assert opposite("marker") is None


@pytest.mark.parametrize(
    ("heard", "commands"),
    [
        # "land" said, "Sealing." heard: the nearest sentence is "ceiling" (a move up).
        ("Sealing.", [{"action": "move", "direction": "up"}]),
        ("Light.", [{"action": "move", "direction": "right"}]),
        ("Fly light two meters.", [{"action": "move", "direction": "right", "distance": 2}]),
        ("Go to marker tree.", [{"action": "goto", "marker": 3}]),
        ("Go still.", [{"action": "goto", "object": "chair"}]),  # flite's "hold still"
    ],
)
def test_a_snap_is_read_back_never_flown(heard: str, commands: list[dict[str, Any]]) -> None:
    rec = choose([(heard, 0.99)], _SNAPPER, cap=THRESHOLD - 0.01)
    assert rec.confidence < THRESHOLD, rec  # never flown on this reading ...
    if rec.commands:
        assert rec.commands == commands and rec.doubt == "snap"
    if heard in ("Sealing.", "Go to marker tree."):  # ... but read back: "Did you say …?"
        assert rec.confidence >= FLOOR


def test_a_reading_heard_whole_is_flown() -> None:
    for heard in ("Fly right two meters.", "Go to marker three.", "Climb one meter."):
        rec = choose([(heard, 0.9)], _SNAPPER, cap=THRESHOLD - 0.01)
        assert rec.confidence >= THRESHOLD and rec.doubt == "", rec


# tiny.en's beams for clips of bench/speech.py that were flown wrong before the doubt rules
# (espeak-ng's and flite's voices): said -> beams.
@pytest.mark.parametrize(
    ("beams", "why"),
    [
        (  # "land immediately"
            [
                ("Climb immediately.", 0.69),
                ("Climb the immediately.", 0.45),
                ("Climb one meter.", 0.37),
                ("Landing immediately.", 0.4),
            ],
            "opposite",
        ),
        (  # "head to marker nine please"
            [
                ("Head to marker eight, please.", 0.65),
                ("Head to marker eight please.", 0.63),
                ("Head to marker, I please.", 0.57),
                ("Head to marker.", 0.44),
            ],
            "contested",
        ),
        (  # "please head right please"
            [
                ("Please turn right, please.", 0.77),
                ("Please turn right please.", 0.77),
                ("Please don' t right, please.", 0.66),
                ("Please don'T right, please.", 0.59),
            ],
            "contested",
        ),
        (  # "get airborne"
            [
                ("Get your forward.", 0.72),
                ("Get your lower.", 0.56),
                ("Get your floor.", 0.43),
                ("Get your blue.", 0.32),
            ],
            "rival",
        ),
    ],
)
def test_a_reading_other_beams_doubt_is_read_back(beams: list[tuple[str, float]], why: str) -> None:
    rec = choose(beams, _SNAPPER, cap=THRESHOLD - 0.01)
    assert rec.doubt == why, rec
    assert rec.confidence < THRESHOLD


def test_beams_that_agree_or_say_nothing_else_leave_the_reading_flown() -> None:
    beams = [("Land.", 0.83), ("land.", 0.23), ("Land?", 0.22), ("Land. Land", 0.23)]
    rec = choose(beams, _SNAPPER, cap=THRESHOLD - 0.01)
    assert rec.commands == [{"action": "land"}] and rec.doubt == ""
    # A query is not flown: other words in a weaker beam do not hold it back.
    beams = [("Altitude.", 0.73), ("All the toad.", 0.56), ("All the toot.", 0.44)]
    rec = choose(beams, _SNAPPER, cap=THRESHOLD - 0.01)
    assert rec.commands == [{"action": "query", "item": "altitude"}] and rec.doubt == ""


@pytest.mark.parametrize(
    "beams",
    [
        [  # hibari-tts, 190 words per minute, 10 dB: the fourth beam ended early
            ("Take off and go to marker two then land.", 0.92),
            ("Take off and go to marker two, then land.", 0.82),
            ("Take off and go to marker two. Then land.", 0.75),
            ("Take off and go to marker two.", 0.72),
        ],
        [  # hibari-tts: "fly to marker eleven"; every beam reads the same goto, snapped
            ("Fly to marker 11.", 0.79),
            ("Fly to marker it 11.", 0.74),
            ("Fly to marker at eleven.", 0.7),
            ("Fly to marker eleven.", 0.68),
        ],
    ],
)
def test_beams_that_end_early_or_snap_to_the_same_commands_agree(
    beams: list[tuple[str, float]],
) -> None:
    rec = choose(beams, _SNAPPER, cap=THRESHOLD - 0.01)
    assert rec.doubt == "" and rec.confidence >= THRESHOLD, rec
