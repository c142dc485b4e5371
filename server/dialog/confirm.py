"""Did you say …? A spoken command heard with middling confidence is read back, and a "yes" runs it.

Below ``confidence_threshold`` a spoken sentence is not flown. When its confidence is still at
least ``confirm_floor`` and the grammars understand all of it, the operator is asked
('Did you say "fly to marker 7"? That is: flying to marker 7. Say yes to do it, or say the
command again.') instead of being asked to repeat the whole command; a sentence that is only a
"yes" (``NLU.answer``: the ``ANSWER`` set of mappings.xml) runs it, checked again against the
drone's state of that moment. Anything else drops the question: a "no", another sentence
(handled as itself), a button acting on the drone, or the question's age (``MAX_AGE_S``), so an
old question never turns a later "yes" into a flight; a yes or no with no question waiting is
told so (``NOTHING_ASKED``, ``EXPIRED``) rather than "I did not understand". bench/speech.py:
at a floor of 0.3, the right command is offered for 11-15 % of the clips that were asked to
repeat before.

A spoken emergency in flight cuts the motors only when it was heard as one: at
:data:`EMERGENCY_CONFIDENCE` or more (and the threshold), its words in the transcript (the
recogniser's snap never makes an emergency, server.speech.snap). Heard less surely, whatever
the confidence, the drone hovers at once and the operator is asked (:func:`emergency_question`);
a "yes" then cuts the motors. Typed text and the Emergency button are never questioned.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from server.dialog import replies
from server.language.nlu import NLU, Interpretation

# A clearly spoken "Emergency stop." reads 0.76-0.79 (hibari-tts's voice, bench/speech.py, all
# speeds and noise levels); a reading under this is doubtful enough to hover and ask instead.
EMERGENCY_CONFIDENCE = 0.6
MAX_AGE_S = 15.0  # the question is spoken (~3 s), heard, and answered
NOT_CONFIRMED = "OK, I will not do that."
NOTHING_ASKED = "No question is waiting for an answer. Please say the command itself."
EXPIRED = "That question has expired. Please say the command again."


@dataclass(frozen=True)
class Pending:
    """A sentence waiting for the operator's yes."""

    text: str
    asked_t: float

    def fresh(self, now: float, max_age_s: float = MAX_AGE_S) -> bool:
        return 0.0 <= now - self.asked_t <= max_age_s


def to_read_back(
    nlu: NLU, sentence: str, confidence: float, threshold: float, floor: float
) -> Interpretation | None:
    """What "Did you say …?" offers for speech heard at ``confidence``, or None: only from
    ``floor`` up to (not including) ``threshold``, and only a sentence the grammars understand
    whole. bench/speech.py counts its read-backs with this too."""
    if not floor <= confidence < threshold:
        return None
    interp = nlu.parse(sentence)
    return interp if interp.commands and not interp.unparsed else None


def question(text: str, commands: Sequence[Mapping[str, Any]]) -> str:
    """What the operator is asked: the sentence as heard and what it would do."""
    said = " ".join(text.replace(" ,", ",").split()).strip(" ,.")
    return (
        f'Did you say "{said}"? That is: {replies.plan(commands)[:-1].lower()}. '
        "Say yes to do it, or say the command again."
    )


def doubtful_emergency(interp: Interpretation, confidence: float, threshold: float) -> bool:
    """Whether a spoken sentence holds an emergency heard under the bar that cuts the motors
    in flight (:data:`EMERGENCY_CONFIDENCE`, at least the dialog's ``threshold``)."""
    if not any(c.get("action") == "emergency" for c in interp.commands):
        return False
    return confidence < max(threshold, EMERGENCY_CONFIDENCE)


def emergency_question(text: str) -> str:
    """What the operator hears when a doubtful emergency made the drone hover instead."""
    said = " ".join(text.replace(" ,", ",").split()).strip(" ,.")
    return (
        f'Hovering. Did you say "{said}"? That is an emergency: it cuts the motors and the '
        "drone falls. Say yes to do it, or say the command again."
    )
