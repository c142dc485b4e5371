"""Vocabulary-constrained decoding: the text tokens Whisper may not write when guided.

Grammar guidance, step 1b (after the prompt, before the snap): every text token that is not
part of a grammar word as Whisper's tokenizer spells it (" take", " Take", "take", "Take",
"TAKE"), nor a number or punctuation, is suppressed at every decoding step (CTranslate2's
``suppress_tokens``: its logit is set to -inf). Whisper can then still write a word the grammars
do not know by joining word pieces, but far less often, and a misheard word lands nearer to a
grammar word for the snap ("Kill them more times" becomes "Kill them more time"; "Disc right
machine" cannot be written at all). The mask costs nothing per step; bench/speech.py measures
the gain.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Protocol

# What a number or a punctuation token may consist of besides digits ("2.5", "45,", "-30", "%").
_NUMBER_CHARS = frozenset(".,?!'-%:")
_SPACE = "\u0120"  # byte-level BPE's spelling of a leading space (GPT-2 bytes_to_unicode)


class HfTokenizer(Protocol):
    """The subset of ``tokenizers.Tokenizer`` used here."""

    def encode(self, sequence: str, add_special_tokens: bool = ...) -> Any: ...

    def id_to_token(self, id: int) -> str | None: ...


def allowed_text_tokens(tokenizer: HfTokenizer, words: Iterable[str], eot: int) -> frozenset[int]:
    """Ids below ``eot`` (Whisper's text tokens) that spell ``words`` in any common casing,
    with or without a leading space, plus every token made of digits and punctuation."""
    allowed: set[int] = set()
    for word in words:
        for variant in {word, word.capitalize(), word.upper()}:
            for spelled in (" " + variant, variant):
                allowed.update(tokenizer.encode(spelled, add_special_tokens=False).ids)
    for token_id in range(eot):
        token = tokenizer.id_to_token(token_id)
        if token is None:
            continue
        bare = token.replace(_SPACE, "")
        if bare and all(ch.isdigit() or ch in _NUMBER_CHARS for ch in bare):
            allowed.add(token_id)
    return frozenset(i for i in allowed if i < eot)


def suppressed_tokens(
    tokenizer: HfTokenizer, words: Iterable[str], eot: int, always: Iterable[int] = ()
) -> list[int]:
    """The ``suppress_tokens`` list for faster-whisper: every text token not allowed (see
    :func:`allowed_text_tokens`) plus ``always`` (the model's own non-speech symbols), sorted."""
    allowed = allowed_text_tokens(tokenizer, words, eot)
    return sorted({i for i in range(eot) if i not in allowed} | set(always))
