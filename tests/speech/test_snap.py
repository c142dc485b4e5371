"""Snapping transcripts to what the grammars accept, and the confidence it costs (no model)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.language.nlu import default_nlu
from server.speech.snap import Snapper
from server.speech.vocabulary import vocabulary

_NLU = default_nlu()
_SNAPPER = Snapper(_NLU, vocabulary(_NLU.grammar))


@pytest.fixture(scope="module")
def snapper() -> Snapper:
    return _SNAPPER


def test_vocabulary_has_the_grammar_words_and_no_regex_fragments() -> None:
    vocab = vocabulary(default_nlu().grammar)
    for word in ("take", "land", "hover", "marker", "patrol", "battery", "three", "ninety"):
        assert word in vocab
    assert "ach" not in vocab  # a fragment of the trie "appro(?:ach|x)"
    assert len(vocab.words) > 300
    assert "marker" in vocab.prompt.lower()


def test_understood_transcript_is_kept_with_distance_zero(snapper: Snapper) -> None:
    s = snapper.snap("Take off and fly to marker three.")
    assert s.complete and s.distance == 0 and s.edits == ()
    assert s.commands == [{"action": "takeoff"}, {"action": "goto", "marker": 3}]


def test_commands_heard_without_a_separator_are_all_kept(snapper: Snapper) -> None:
    # "land. take off." spoken, "Land take off." heard: the snap dropped "land" and the
    # take-off alone was executed (bench/speech.py's second clip set, 2 of 18 clips).
    s = snapper.snap("Land take off.")
    assert s.complete and s.distance == 0
    assert s.commands == [{"action": "land"}, {"action": "takeoff"}]


@pytest.mark.parametrize(
    ("heard", "commands"),
    [
        ("go to marker tree", [{"action": "goto", "marker": 3}]),
        (
            "Take off and fly to Marco free.",
            [{"action": "takeoff"}, {"action": "goto", "marker": 3}],
        ),
        ("hoover", [{"action": "hover"}]),
        ("lend", [{"action": "land"}]),
        ("what do you sea", [{"action": "describe"}]),
        ("fly forward to meters", [{"action": "move", "direction": "forward", "distance": 2}]),
    ],
)
def test_misheard_words_snap_to_the_grammar(
    snapper: Snapper, heard: str, commands: list[dict[str, object]]
) -> None:
    s = snapper.snap(heard)
    assert s.complete
    assert s.commands == commands
    assert 0 < s.distance < 1.0
    assert s.edits


def test_confidence_factor_drops_with_distance(snapper: Snapper) -> None:
    near = snapper.snap("hoover")  # one letter off
    far = snapper.snap("Take off and fly to Marco free.")  # two words replaced
    nonsense = snapper.snap("blah blah banana")
    assert 1.0 > near.factor > far.factor
    # Nonsense is either left alone (no command: "not understood") or, where it can only be
    # bent into a command, lands under the dialog's 0.5 threshold even when the recogniser
    # was sure of what it heard.
    assert nonsense.commands == [] or (far.factor > nonsense.factor and nonsense.factor < 0.5)


def test_ordinary_speech_is_not_turned_into_a_command(snapper: Snapper) -> None:
    s = snapper.snap("I would like to order a pizza with extra cheese and some cola")
    assert not s.complete and s.commands == [] and s.distance == 0


def test_search_is_bounded(snapper: Snapper) -> None:
    small = Snapper(snapper.nlu, snapper.vocab, max_attempts=5)
    calls = 0
    parse = small.nlu.parse

    class Counting:
        def parse(self, text: str, state: str | None = None):  # type: ignore[no-untyped-def]
            nonlocal calls
            calls += 1
            return parse(text, state)

    small.nlu = Counting()  # type: ignore[assignment]
    small.snap("the quick brown fox jumps over the lazy dog")
    assert calls <= 1 + 5 + small.runner_up_attempts


@pytest.mark.parametrize(
    ("heard", "wrong"),
    [
        # Transcripts of bench/speech.py misses (espeak-ng, tiny.en): what was said -> heard.
        ("Take off and then, Herman.", [{"action": "takeoff"}]),  # "take off then hover"
        ("Take off men, Palmer.", [{"action": "takeoff"}, {"action": "query", "item": "state"}]),
    ],
)
def test_a_snap_with_a_near_runner_up_is_a_guess(
    snapper: Snapper, heard: str, wrong: list[dict[str, object]]
) -> None:
    """Another reading nearly as near: the margin gate pushes the guess under the 0.5
    threshold even at full decoder confidence, so the operator is asked to repeat."""
    s = snapper.snap(heard)
    if s.commands == []:  # no reading within the search bound: "not understood", nothing flies
        return
    assert s.commands == wrong  # the nearest reading is wrong ...
    assert s.margin < 0.05
    assert s.factor < 0.5  # ... and is not flown


def test_a_clear_snap_keeps_most_of_its_confidence(snapper: Snapper) -> None:
    s = snapper.snap("go to marker tree")
    assert s.commands == [{"action": "goto", "marker": 3}]
    # The merged grammars (objects as targets, "mark") hold nearer other readings than the
    # marker-only grammar did; the snap still keeps most of its confidence.
    assert s.margin > 0.1 and s.factor > 0.6
    side = snapper.snap("Please side one meter downward.")  # runner-up 0.22 further
    assert side.commands == [{"action": "move", "direction": "down", "distance": 1}]
    assert side.factor > 0.7


def test_understood_as_heard_has_no_runner_up(snapper: Snapper) -> None:
    s = snapper.snap("land")
    assert s.distance == 0 and math.isinf(s.margin) and s.factor == 1.0


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.text(max_size=60))
def test_arbitrary_text_never_raises(text: str) -> None:
    s = _SNAPPER.snap(text)
    assert 0.0 <= s.factor <= 1.0
    assert s.distance >= 0 and s.margin >= 0
