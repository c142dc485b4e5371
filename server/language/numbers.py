"""Spoken numbers to digits: "twenty five" -> 25, "one and a half" -> 1.5, "half a" -> 0.5.

Works on normalised text (lower case, single spaces). Runs of number words become one number;
adjacent simple numbers stay separate ("one three five" -> "1 3 5", as in a marker list), except
the spoken-hundreds idiom "one eighty" -> 180 (as in "turn one eighty").
"""

from __future__ import annotations

import re

ONES: dict[str, int] = {
    "zero": 0,
    "one": 1,
    "two": 2,
    "three": 3,
    "four": 4,
    "five": 5,
    "six": 6,
    "seven": 7,
    "eight": 8,
    "nine": 9,
}
TEENS: dict[str, int] = {
    "ten": 10,
    "eleven": 11,
    "twelve": 12,
    "thirteen": 13,
    "fourteen": 14,
    "fifteen": 15,
    "sixteen": 16,
    "seventeen": 17,
    "eighteen": 18,
    "nineteen": 19,
}
TENS: dict[str, int] = {
    "twenty": 20,
    "thirty": 30,
    "forty": 40,
    "fourty": 40,
    "fifty": 50,
    "sixty": 60,
    "seventy": 70,
    "eighty": 80,
    "ninety": 90,
}
FRACTIONS: dict[str, float] = {"half": 0.5, "quarter": 0.25}
_DIGITS = re.compile(r"\d+(?:\.\d+)?")
_WORDS = {*ONES, *TEENS, *TENS, "hundred", "thousand", "half", "quarter", "couple", "dozen"}


def _fmt(value: float) -> str:
    if value == int(value) and abs(value) < 1e15:
        return str(int(value))
    return f"{value:.6f}".rstrip("0").rstrip(".")


def _is_num(tok: str) -> bool:
    return tok in ONES or tok in TEENS or tok in TENS or _DIGITS.fullmatch(tok) is not None


def _parse_int(toks: list[str], i: int) -> tuple[float | None, int]:
    """An integer spelled in words starting at ``toks[i]``; (None, i) if there is none."""
    n = len(toks)
    total = 0
    current = 0
    last: str | None = None  # kind of the previous word: ones, teens, tens, hundred, thousand
    j = i
    while j < n:
        w = toks[j]
        if w in ONES:
            if last in (None, "hundred", "thousand") or (last == "tens" and current % 10 == 0):
                current += ONES[w]
                last = "ones"
            else:
                break
        elif w in TEENS:
            if last in (None, "hundred", "thousand"):
                current += TEENS[w]
                last = "teens"
            else:
                break
        elif w in TENS:
            if last in (None, "hundred", "thousand"):
                current += TENS[w]
            elif last == "ones" and 0 < current < 10 and total == 0:
                current = current * 100 + TENS[w]  # "one eighty" = 180
            else:
                break
            last = "tens"
        elif w == "hundred":
            if last is None:
                current = 100
            elif last in ("ones", "teens", "tens") and current < 100:
                current *= 100
            else:
                break
            last = "hundred"
        elif w == "thousand":
            if last == "thousand" or total:
                break
            total += (current or 1) * 1000
            current = 0
            last = "thousand"
        elif w == "and" and last in ("hundred", "thousand") and j + 1 < n:
            nxt = toks[j + 1]
            if nxt in ONES or nxt in TEENS or nxt in TENS:
                j += 1
                continue
            break
        else:
            break
        j += 1
    if last is None:
        return None, i
    return float(total + current), j


def _skip_of_a(toks: list[str], j: int) -> int:
    """Skip "of a", "of an" or "a" after a fraction ("a quarter of a meter", "half a meter")."""
    if toks[j : j + 2] in (["of", "a"], ["of", "an"]):
        return j + 2
    if j < len(toks) and toks[j] in ("a", "an", "of"):
        return j + 1
    return j


def _parse_number(toks: list[str], i: int) -> tuple[float | None, int]:
    """A number starting at ``toks[i]``: words, digits, fractions; (None, i) if none."""
    n = len(toks)
    w = toks[i]
    nxt = toks[i + 1] if i + 1 < n else ""
    if w in ("a", "an"):
        if nxt == "half" or nxt == "quarter":
            return FRACTIONS[nxt], _skip_of_a(toks, i + 2)
        if nxt == "couple":
            return 2.0, i + 3 if i + 2 < n and toks[i + 2] == "of" else i + 2
        if nxt == "dozen":
            return 12.0, i + 2
        if nxt in ("hundred", "thousand"):
            hundreds, k = _parse_int(["one", *toks[i + 1 :]], 0)
            return hundreds, i + k
        return None, i
    if w in FRACTIONS:
        return FRACTIONS[w], _skip_of_a(toks, i + 1)
    if _DIGITS.fullmatch(w):
        value: float | None = float(w)
        j = i + 1
    else:
        value, j = _parse_int(toks, i)
        if value is None:
            return None, i
    assert value is not None
    # decimals: "three point five", "zero point two five"
    if j + 1 < n and toks[j] == "point" and (toks[j + 1] in ONES or toks[j + 1].isdigit()):
        digits = ""
        k = j + 1
        while k < n and (toks[k] in ONES or toks[k].isdigit()):
            digits += str(ONES[toks[k]]) if toks[k] in ONES else toks[k]
            k += 1
        value = float(f"{int(value)}.{digits}")
        j = k
    # "one and a half", "2 and a quarter"
    if j + 2 < n and toks[j] == "and" and toks[j + 1] in ("a", "an") and toks[j + 2] in FRACTIONS:
        value += FRACTIONS[toks[j + 2]]
        j += 3
    elif j < n and toks[j] in ("quarters", "halves", "quarter", "half") and 0 < value < 10:
        value *= 0.25 if toks[j].startswith("quarter") else 0.5
        j = _skip_of_a(toks, j + 1)
    elif j < n and toks[j] == "dozen":
        value *= 12
        j += 1
    return value, j


def words_to_numbers(text: str) -> str:
    """Replace spoken numbers in normalised ``text`` by digits.

    >>> words_to_numbers("climb one and a half meters then turn a hundred and eighty")
    'climb 1.5 meters then turn 180'
    """
    toks = text.split(" ")
    if _WORDS.isdisjoint(toks):
        return text
    out: list[str] = []
    i = 0
    n = len(toks)
    while i < n:
        tok = toks[i]
        if tok in _WORDS or tok in ("a", "an") or (tok[:1].isdigit() and _DIGITS.fullmatch(tok)):
            value, j = _parse_number(toks, i)
            if value is not None and j > i:
                out.append(_fmt(value))
                i = j
                continue
        out.append(tok)
        i += 1
    return " ".join(out)
