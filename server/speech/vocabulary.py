"""The words the XML grammars understand, for biasing the decoder and snapping its output.

Every word the NLU can match appears literally in a rule pattern (after ``{SET}`` expansion) or
in a mappings.xml set; numbers are spoken as number words. Whisper is told these words through
its initial prompt (the ``prompt`` field of the decoder: text the model treats as having just been
said, openai/whisper decoding.py ``DecodingOptions.prompt``), which raises their probability
without forcing them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from server.language.grammar import Grammar
from server.language.numbers import ONES, TEENS, TENS

# Regex syntax that must not be read as words: group names, escapes, inline flags.
_SYNTAX = re.compile(r"\(\?P<\w+>|\(\?P=\w+\)|\\[a-zA-Z]|\(\?[a-zA-Z]+\)|\{\d+(?:,\d*)?\}")
_WORD = re.compile(r"[a-z]+")
_NUMBER_WORDS = (*ONES, *TEENS, *TENS, "hundred", "thousand", "half", "quarter", "point")

# The initial prompt: a few commands as an operator says them, covering the words Whisper gets
# wrong without help ("marker", number words, "take off", "hover"). Whisper's prompt is capped
# at 223 tokens (openai/whisper decoding.py: n_ctx // 2 - 1); this is about 60.
PROMPT = (
    "Take off. Fly forward two meters. Go to marker three. Turn left ninety degrees. Hover. "
    "Climb one meter. Patrol markers one, four and seven. Land. Return home. What do you see? "
    "How much battery is left? Emergency stop."
)


@dataclass(frozen=True)
class Vocabulary:
    """Words the grammars can match, and the prompt that biases the decoder towards them."""

    words: frozenset[str]
    prompt: str

    def __contains__(self, word: object) -> bool:
        return word in self.words


def vocabulary(grammar: Grammar) -> Vocabulary:
    """Collect the vocabulary of ``grammar`` (rule patterns, every set, number words)."""
    words: set[str] = set(_NUMBER_WORDS)
    # Sets are expanded into the patterns as tries ("appro(?:ach|x)"), whose fragments are not
    # words: cut them out and take the set's words from its labels instead.
    set_regexes = sorted((ws.regex for ws in grammar.sets.values()), key=len, reverse=True)
    for rule in grammar.rules:
        pattern = rule.pattern
        for regex in set_regexes:
            pattern = pattern.replace(regex, " ")
        words.update(_WORD.findall(_SYNTAX.sub(" ", pattern)))
    for ws in grammar.sets.values():
        for phrase in ws.labels:
            words.update(_WORD.findall(phrase.lower()))
        for value in ws.labels.values():
            words.update(_WORD.findall(str(value).lower()))
    # Single letters left over from character classes ("[sz]") are not words anyone says,
    # except "a" and "i".
    words = {w for w in words if len(w) > 1 or w in ("a", "i")}
    return Vocabulary(frozenset(words), PROMPT)
