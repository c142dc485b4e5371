"""Help for the operator: examples for the current state, and "Did you mean …?".

``help_text(state)`` answers "help" / "what can you do?" with sentences the grammar understands
in that state (tests check every example parses to a command, so help never teaches a sentence
the console would not take). ``suggest(text, nlu, state)`` finds the example closest to a
sentence that was not understood (difflib's ratio over normalised words) and puts the
operator's own numbers into it: "fly too marker 3" -> "go to marker 3".
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Sequence
from typing import Protocol

from server.dialog.states import State

# Sentences the grammar understands; the first number in one is replaced by the operator's.
GROUND_EXAMPLES = (
    "take off",
    "how much battery is left",
    "what is your status",
    "what do you see",
)
FLIGHT_EXAMPLES = (
    "go to marker 3",
    "turn left 90 degrees",
    "turn around",
    "climb 1 meter",
    "move forward 1 meter",
    "patrol markers 1, 2 and 3",
    "patrol all markers",
    "come back",
    "hover",
    "land",
)
ALWAYS_EXAMPLES = ("cancel", "emergency stop", "where are you", "help")
# Candidates for "Did you mean …?" (every state's examples, plus common variants).
SUGGESTIONS = (
    *GROUND_EXAMPLES,
    *FLIGHT_EXAMPLES,
    *ALWAYS_EXAMPLES,
    "turn right 90 degrees",
    "turn left 180 degrees",
    "move left 1 meter",
    "move right 1 meter",
    "move back 1 meter",
    "go down 1 meter",
    "what is your altitude",
)
MIN_RATIO = 0.6  # below this the closest example is a guess, not a suggestion
_NUMBER = re.compile(r"\d+(?:\.\d+)?")


class NLULike(Protocol):
    def normalise(self, text: str) -> str: ...
    def interpret(self, text: str, state: str | None = None) -> list[dict[str, object]]: ...


def _quote(items: Sequence[str]) -> str:
    quoted = [f"“{s}”" for s in items]
    return ", ".join(quoted[:-1]) + " or " + quoted[-1] if len(quoted) > 1 else quoted[0]


def help_text(state: State) -> str:
    """What the operator can say now, with examples (short enough to be spoken)."""
    if state is State.EMERGENCY:
        return (
            "The motors are cut (emergency). Press Reset, then say “take off”. "
            "You can still ask “what is your status”."
        )
    if state in (State.LANDED, State.LANDING):
        return (
            f"I am on the ground. Say {_quote(GROUND_EXAMPLES)}. Once flying: "
            f"{_quote(FLIGHT_EXAMPLES[:4])}. “Emergency stop” cuts the motors."
        )
    return (
        f"I am flying. Say {_quote(FLIGHT_EXAMPLES)}. “Stop” holds position; "
        "“emergency stop” cuts the motors. In a fleet, name the drone first: “uav2, land”."
    )


def _with_numbers(example: str, numbers: list[str]) -> str:
    if not numbers:
        return example
    it = iter(numbers)
    return _NUMBER.sub(lambda m: next(it, m.group(0)), example)


def suggest(text: str, nlu: NLULike) -> str | None:
    """The example closest to ``text`` (with its numbers) that the grammar understands.

    Returns None when nothing is close enough to be a fair guess.
    """
    said = nlu.normalise(text)
    if not said.strip():
        return None
    numbers = _NUMBER.findall(said)
    best: tuple[float, str] | None = None
    for example in SUGGESTIONS:
        candidate = _with_numbers(example, numbers)
        ratio = difflib.SequenceMatcher(None, said, nlu.normalise(candidate)).ratio()
        if best is None or ratio > best[0]:
            best = (ratio, candidate)
    if best is None or best[0] < MIN_RATIO:
        return None
    if not nlu.interpret(best[1]):
        return None  # the operator's numbers made it a sentence the grammar does not take
    return best[1]


def not_understood(text: str, nlu: NLULike) -> str:
    """The reply to a sentence nothing of which was understood."""
    guess = suggest(text, nlu)
    if guess is not None:
        return (
            f"Sorry, I did not understand. Did you mean “{guess}”? "
            "Or rephrase; “help” lists examples."
        )
    return "Sorry, I did not understand. Could you rephrase? Say “help” to hear what I can do."


# Validation messages of server.tasks (CommandError) are written for programmers; these say the
# same to the operator ("'turn' needs 'direction' left or right; got None" must never
# reach a person).
_RANGE = re.compile(
    r"^(?P<what>move distance|turn angle) must be in \(0, (?P<max>[\d.]+)\] (?P<unit>m|degrees), "
    r"got (?P<got>[-\d.e+]+)"
)
_NEEDS = re.compile(r"^'(?P<action>\w+)' needs '(?P<slot>\w+)'")


def operator_words(reason: str) -> str:
    """``reason`` as a sentence for the operator (unchanged when it already is one)."""
    m = _RANGE.match(reason)
    if m:
        got = float(m.group("got"))
        if m.group("what") == "turn angle":
            return (
                f"I can turn by up to {float(m.group('max')):g} degrees at a time; "
                f"you asked for {got:g}."
            )
        return (
            f"I can move up to {float(m.group('max')):g} meters at a time; you asked for {got:g}. "
            "Try a marker instead: “go to marker 3”."
        )
    m = _NEEDS.match(reason)
    if m:
        action, slot = m.group("action"), m.group("slot")
        example = {
            "turn": "turn left 90 degrees",
            "move": "move forward 1 meter",
            "goto": "go to marker 3",
            "patrol": "patrol markers 1, 2 and 3",
        }.get(action, "help")
        return f"I need to know the {slot} for that. For example: “{example}”."
    return reason
