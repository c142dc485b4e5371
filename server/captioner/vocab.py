"""The captioner's vocabulary: ``vocab.json`` <-> token ids, and token ids -> a sentence.

File format (documented in ``models/captioner/MODEL.md``)::

    {"format": "uav-console-captioner-vocab/1",
     "tokens": ["<pad>", "<bos>", "<eos>", "<unk>", "a", "red", ...],
     "pad": "<pad>", "bos": "<bos>", "eos": "<eos>", "unk": "<unk>"}

Token id ``i`` is ``tokens[i]``; the decoder's logits have one column per token.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from server.captioner.errors import CaptionerUnavailable

FORMAT = "uav-console-captioner-vocab/1"
SPECIALS = ("pad", "bos", "eos", "unk")


@dataclass(frozen=True)
class Vocab:
    """Token list plus the ids of the special tokens."""

    tokens: tuple[str, ...]
    pad: int
    bos: int
    eos: int
    unk: int

    def __len__(self) -> int:
        return len(self.tokens)

    @classmethod
    def build(cls, words: Iterable[str]) -> Vocab:
        """Specials first (ids 0..3), then ``words`` in sorted order, without duplicates."""
        specials = ["<pad>", "<bos>", "<eos>", "<unk>"]
        rest = sorted(set(words) - set(specials))
        return cls(tuple(specials + rest), pad=0, bos=1, eos=2, unk=3)

    def encode(self, sentence: str) -> list[int]:
        """Word ids of a lower-cased, space-separated sentence (no bos/eos); unknown -> unk."""
        index = {t: i for i, t in enumerate(self.tokens)}
        return [index.get(w, self.unk) for w in tokenize(sentence)]

    def words(self, ids: Sequence[int]) -> list[str]:
        """The words of ``ids``, stopping at eos and dropping pad/bos."""
        out: list[str] = []
        for i in ids:
            if i == self.eos:
                break
            if i in (self.pad, self.bos):
                continue
            out.append(self.tokens[i] if 0 <= i < len(self.tokens) else self.tokens[self.unk])
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "tokens": list(self.tokens),
            "pad": self.tokens[self.pad],
            "bos": self.tokens[self.bos],
            "eos": self.tokens[self.eos],
            "unk": self.tokens[self.unk],
        }

    def save(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_json(), indent=1) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: Path) -> Vocab:
        """Read and check ``vocab.json``.

        Raises:
            CaptionerUnavailable: missing file, bad JSON, or a malformed token table.
        """
        if not path.is_file():
            raise CaptionerUnavailable(f"{path.name} is missing from {path.parent}")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CaptionerUnavailable(f"{path.name} is not valid JSON: {exc}") from exc
        return cls.from_json(data, name=path.name)

    @classmethod
    def from_json(cls, data: Any, *, name: str = "vocab.json") -> Vocab:
        if not isinstance(data, dict):
            raise CaptionerUnavailable(f"{name} must hold a JSON object")
        tokens = data.get("tokens")
        if (
            not isinstance(tokens, list)
            or not tokens
            or not all(isinstance(t, str) and t for t in tokens)
        ):
            raise CaptionerUnavailable(f"{name}: 'tokens' must be a non-empty list of strings")
        if len(set(tokens)) != len(tokens):
            raise CaptionerUnavailable(f"{name}: 'tokens' has duplicates")
        ids: dict[str, int] = {}
        for key in SPECIALS:
            tok = data.get(key, f"<{key}>")
            if tok not in tokens:
                raise CaptionerUnavailable(
                    f"{name}: special token {key}={tok!r} is not in 'tokens'"
                )
            ids[key] = tokens.index(tok)
        return cls(tuple(tokens), **ids)


def tokenize(sentence: str) -> list[str]:
    """Lower-case words and commas (a token of their own); other punctuation is dropped."""
    cleaned = "".join(
        c if c.isalnum() or c in "' " else " , " if c == "," else " " for c in sentence.lower()
    )
    return cleaned.split()


def detokenize(words: Sequence[str]) -> str:
    """Words -> a sentence: first letter capitalised, full stop at the end ('' for no words)."""
    if not words:
        return ""
    text = " ".join(words).replace(" ,", ",")
    return text[0].upper() + text[1:] + "."
