"""Questions back to the operator and their answers : "go to the chair" in a
room with two chairs is answered "Which chair? The red one or the blue one?"; the next sentence,
"the red one" (a ``choose`` command: ``colour``/``which``/``object`` slots), completes the
command that asked, and the sentence it was part of ("take off and go to the chair") runs as if
it had been said whole. Any other sentence drops the
question; so does its age (``max_age_s``), so an old question never turns a later "red" into a
flight.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from server.language.nlu import Interpretation, Parsed

ANSWER_SLOTS = ("colour", "which")
MAX_AGE_S = 60.0


@dataclass(frozen=True)
class Question:
    """A sentence refused with a question about its command ``index``, waiting for the answer."""

    parsed: tuple[Parsed, ...]
    index: int
    asked_t: float


def is_answer(interp: Interpretation) -> bool:
    """Whether the sentence is only an answer ("the red one", "the north one")."""
    return bool(interp.parsed) and all(p.command["action"] == "choose" for p in interp.parsed)


def complete(
    question: Question | None, interp: Interpretation, now: float, max_age_s: float = MAX_AGE_S
) -> Interpretation | str:
    """The asked command completed by the answer in ``interp``, or why it cannot be."""
    if question is None or now - question.asked_t > max_age_s:
        return "I did not ask you to choose anything. Please say the whole command."
    asked = question.parsed[question.index]
    cmd = dict(asked.command)
    kind = cmd.get("object")
    for p in interp.parsed:
        said = p.command
        if "object" in said and said["object"] != kind:
            return f"I asked which {kind}, not about a {said['object']}."
        for slot in ANSWER_SLOTS:
            if slot in said:
                cmd.pop("which" if slot == "colour" else "colour", None)
                cmd[slot] = said[slot]
    parsed = list(question.parsed)
    parsed[question.index] = replace(asked, command=cmd)
    return Interpretation(interp.text, interp.normalised, tuple(parsed), ())
