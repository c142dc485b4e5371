"""Vocabulary-constrained decoding with the shipped model's real tokenizer."""

from __future__ import annotations

import pytest

from server.language.nlu import default_nlu
from server.speech.constraint import allowed_text_tokens, suppressed_tokens
from server.speech.model import bundled_dir
from server.speech.vocabulary import vocabulary

EOT = 50256  # tiny.en's <|endoftext|>: the first special token, after every text token


@pytest.fixture(scope="module")
def tokenizer():  # type: ignore[no-untyped-def]
    from tokenizers import Tokenizer

    return Tokenizer.from_file(str(bundled_dir() / "tokenizer.json"))


def ids(tokenizer, text: str) -> list[int]:  # type: ignore[no-untyped-def]
    return list(tokenizer.encode(text, add_special_tokens=False).ids)


def test_grammar_words_numbers_and_punctuation_stay_writable(tokenizer) -> None:  # type: ignore[no-untyped-def]
    words = vocabulary(default_nlu().grammar).words
    allowed = allowed_text_tokens(tokenizer, words, EOT)
    for text in (" Take off.", " Fly forward 2.5 meters,", " Go to marker 30!", " LAND"):
        assert set(ids(tokenizer, text)) <= allowed, text
    # Words no grammar has cannot be written whole: the decoder must pick near grammar words.
    for text in (" machine", " Council", " elephant"):
        assert not set(ids(tokenizer, text)) <= allowed, text
    assert all(i < EOT for i in allowed)


def test_the_suppress_list_is_the_rest_plus_the_models_symbols(tokenizer) -> None:  # type: ignore[no-untyped-def]
    words = vocabulary(default_nlu().grammar).words
    allowed = allowed_text_tokens(tokenizer, words, EOT)
    digit = ids(tokenizer, "7")[0]
    assert digit in allowed
    suppress = suppressed_tokens(tokenizer, words, EOT, always=[digit])
    assert digit in suppress  # what the caller always suppresses stays suppressed
    assert set(suppress) == (set(range(EOT)) - allowed) | {digit}
    assert EOT not in suppress and suppress == sorted(suppress)
