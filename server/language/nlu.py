"""Regular-expression NLU driven by the XML grammars: text -> commands of DESIGN §4.

Pipeline (each step one compiled regular expression over the whole utterance):
  1. lower case, REWRITE phrases (contractions, idioms), punctuation to spaces or " , ";
  2. spoken numbers to digits (``numbers.words_to_numbers``), "a meter" -> "1 meter";
  3. FILLER words removed ("please", "uh", "the", "drone");
  4. split at SPLIT words and commas into pieces; from the left, the longest run of pieces (up
     to four) that one active rule matches *entirely* becomes a command, so "patrol markers 1, 3
     and 5" stays one command and "take off and land" becomes two;
  5. slots are converted (labels, metres, degrees, integers); unmatched slots are omitted.

Anything not matched is left out; an utterance with nothing matched gives ``[]``, never a guess.

A command is the flat JSON object of DESIGN §4, keys in the grammar's order, as the page and
the recordings see it; :meth:`Parsed.typed` and :meth:`Interpretation.typed_commands` read it
as the typed union of drone/commands.py, which every rule of the project's grammars produces.
"""

from __future__ import annotations

import functools
import math
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from drone.commands import Command as TypedCommand
from drone.commands import parse_command
from drone.share import share_dir
from server.language.errors import GrammarError
from server.language.grammar import Grammar, Matcher, Slot, load_grammar, trie_regex
from server.language.numbers import words_to_numbers

Command = dict[str, Any]
Answer = Literal["yes", "no"]
MAX_UTTERANCE_CHARS = 1000  # longer text is not speech; interpret() answers [] (documented)
MAX_PIECES = 32
MAX_WINDOW = 4  # a command spans at most this many split pieces
# A piece no rule matches may be commands said back to back with no separator ("land take
# off": a speech recogniser often writes no comma between them); it is split at word
# boundaries into at most this many commands, if its words are few enough (bounded parses).
MAX_RUN_COMMANDS = 3
MAX_RUN_WORDS = 12
DEFAULT_GRAMMAR_DIR = share_dir("grammars")
ANSWER_SET = "ANSWER"  # mappings.xml: the phrases that answer a question, labelled yes or no
_NOT_ANSWER_CHAR = re.compile(r"[^a-z0-9 ]+")

_APOSTROPHES = str.maketrans({"\u2019": "'", "\u2018": "'", "`": "'", "\u00b4": "'"})
_DIGIT_COMMA = re.compile(r"(?<=\d),(?=\d{3}\b)")  # 1,000 -> 1000
_LEAD_DOT = re.compile(r"(?<![\d.])\.(?=\d)")  # ".5" -> "0.5"
_SPLIT_DOT = re.compile(r"\.(?!\d)|(?<!\d)\.")  # a dot that is not a decimal point ends a clause
# One str.translate for all ASCII punctuation: separators become " , ", symbols words, the
# rest spaces ('.' is left to _DOTS, which knows decimals).
_PUNCT: dict[int, str] = {c: " " for c in range(128) if not chr(c).isalnum() and chr(c) != "."}
_PUNCT.update({ord(c): " , " for c in ",;:!?"})
_PUNCT.update({ord("#"): " number ", ord("%"): " percent ", ord("&"): " and ", ord("+"): " and "})
_PUNCT.update({ord("'"): "", ord("-"): " ", ord("\u00b0"): " degrees "})
_PUNCT_TABLE = str.maketrans(_PUNCT)
_NON_ASCII = re.compile(r"[^a-z0-9., ]+")
_DIGIT_ALPHA = re.compile(r"(\d)(?!(?:st|nd|rd|th)\b)(?=[a-z])|(?<=[a-z])(?=\d)")
_HAS_DIGIT = re.compile(r"\d")
_NUMBER = re.compile(r"\d+(?:\.\d+)?")
_SIGNED = re.compile(r"(?<![\w.])[-\u2212\u2013]\s*(?=\.?\d)")  # "-5", "− 5": a signed number
_INT = re.compile(r"\d+")


class _Reject(Exception):
    """A slot value cannot be used (e.g. a number too large to be finite): rule does not apply."""


@dataclass(frozen=True)
class Parsed:
    """One understood command and where it came from."""

    command: Command
    rule: str
    grammar: str
    text: str  # the normalised clause it was read from
    chains: bool = True  # may be read out of commands said back to back (rules.xml chain=)

    def typed(self) -> TypedCommand:
        """The command as the typed union.

        Raises:
            InvalidCommand: a grammar edited to produce an action or slot the union lacks.
        """
        return parse_command(self.command)


@dataclass(frozen=True)
class Interpretation:
    """The result of :meth:`NLU.parse`: commands in spoken order plus what was not understood."""

    text: str
    normalised: str
    parsed: tuple[Parsed, ...] = ()
    unparsed: tuple[str, ...] = ()

    @property
    def commands(self) -> list[Command]:
        return [dict(p.command) for p in self.parsed]

    def typed_commands(self) -> list[TypedCommand]:
        """The commands as the typed union, in spoken order (see :meth:`Parsed.typed`)."""
        return [p.typed() for p in self.parsed]


def _alternation(words: list[str]) -> str:
    return trie_regex(words)


@dataclass(frozen=True)
class _Normaliser:
    """The normalisation regexes built from the grammar's reserved sets."""

    rewrite: re.Pattern[str]
    rewrite_map: dict[str, str]
    filler: re.Pattern[str]
    lead: re.Pattern[str]
    split: re.Pattern[str]
    one_unit: re.Pattern[str]
    unit_fraction: re.Pattern[str]

    @classmethod
    def build(cls, grammar: Grammar) -> _Normaliser:
        def words(name: str) -> list[str]:
            ws = grammar.sets.get(name)
            return list(ws.labels) if ws else []

        rewrite_map = dict(grammar.sets["REWRITE"].labels) if "REWRITE" in grammar.sets else {}
        unit_words = words("DIST_UNIT") + words("ANGLE_UNIT")
        return cls(
            rewrite=re.compile(r"(?<![\w'])(?:" + _alternation(list(rewrite_map)) + r")(?![\w'])"),
            rewrite_map=rewrite_map,
            filler=re.compile(r"(?<![^ ])(?:" + _alternation(words("FILLER")) + r")(?![^ ])"),
            lead=re.compile(r"^(?:(?:" + _alternation(words("LEAD")) + r")(?: |$))+"),
            split=re.compile(r"(?:^| )(,|" + _alternation(words("SPLIT")) + r")(?= |$)"),
            one_unit=re.compile(r"(?<![^ ])an? (?=(?:" + _alternation(unit_words) + r")(?: |$))"),
            unit_fraction=re.compile(
                r"(?<![^ ])(\d+(?:\.\d+)?) ("
                + _alternation(unit_words)
                + r") and (0\.5|0\.25)(?![^ ])"
            ),
        )

    def normalise(self, text: str) -> str:
        """Lower case, rewrites, punctuation, numbers and fillers; separators kept as ','."""
        s = text.lower().translate(_APOSTROPHES)
        s = self.rewrite.sub(lambda m: self.rewrite_map[m.group(0)], s)
        digits = _HAS_DIGIT.search(s) is not None
        if digits and ("-" in s or "\u2212" in s or "\u2013" in s):
            # A sign is kept as the word "minus", which no rule accepts: "go forward -5
            # meters" is refused rather than flown forward without its sign.
            s = _SIGNED.sub(" minus ", s)
        if digits and "," in s:
            s = _DIGIT_COMMA.sub("", s)
        s = s.translate(_PUNCT_TABLE)
        if "." in s:
            s = _SPLIT_DOT.sub(" , ", _LEAD_DOT.sub("0.", s))
        if not s.isascii():
            s = _NON_ASCII.sub(" ", s.replace("\u00b0", " degrees "))
        if digits:
            s = _DIGIT_ALPHA.sub(r"\1 ", s)
        s = " ".join(s.split())
        s = words_to_numbers(s)
        s = self.one_unit.sub("1 ", s)
        if " and " in s:  # "1 meter and 0.5" (one meter and a half) -> "1.5 meter"
            s = self.unit_fraction.sub(_add_fraction, s)
        s = self.filler.sub("", s)
        return " ".join(s.split())


def _add_fraction(m: re.Match[str]) -> str:
    value = float(m.group(1)) + float(m.group(3))
    return f"{value:g} {m.group(2)}"


@dataclass(frozen=True)
class _Compiled:
    grammar: Grammar
    norm: _Normaliser

    @classmethod
    def build(cls, grammar: Grammar) -> _Compiled:
        return cls(grammar, _Normaliser.build(grammar))


def _number(value: float) -> int | float:
    if not math.isfinite(value):
        raise _Reject(value)
    rounded = round(value, 6)
    if rounded == int(rounded):
        return int(rounded)
    return rounded


def _slot_value(grammar: Grammar, slot: Slot, raw: str) -> Any:
    if slot.type == "label":
        assert slot.set is not None
        return grammar.sets[slot.set].labels.get(raw, raw)
    if slot.type == "int":
        text = grammar.sets[slot.set].labels.get(raw, raw) if slot.set else raw
        digits = _INT.search(text)
        if digits is None:
            raise _Reject(raw)
        return int(digits.group(0))
    if slot.type == "int_list":
        return [int(x) for x in _INT.findall(raw)]
    if slot.type == "int_range":
        ends = [int(x) for x in _INT.findall(raw)]
        a, b = ends[0], ends[-1]
        if abs(b - a) > 100:
            return [a, b]
        step = 1 if b >= a else -1
        return list(range(a, b + step, step))
    if slot.type == "quantity":
        num = _NUMBER.search(raw)
        if num is None:
            raise _Reject(raw)
        value = float(num.group(0))
        if slot.units:
            values = grammar.sets[slot.units].values
            toks = raw[num.end() :].split()
            for i in range(len(toks)):
                two = " ".join(toks[i : i + 2])
                factor = values.get(two) if i + 1 < len(toks) else None
                if factor is None:
                    factor = values.get(toks[i])
                if factor is not None:
                    value *= factor
                    break
        return _number(value)
    return raw


def _command(grammar: Grammar, matcher: Matcher, clause: str) -> Parsed | None:
    found = matcher.fullmatch(clause)
    if found is None:
        return None
    m, rule, slots = found
    cmd: Command = {"action": rule.action}
    for name, value in rule.consts:
        cmd[name] = value
    filled: set[str] = set()
    try:
        for slot, group in slots:
            if slot.name in filled:
                continue
            raw = m.group(group)
            if raw is None:
                continue
            cmd[slot.name] = _slot_value(grammar, slot, raw)
            filled.add(slot.name)
    except _Reject:
        return None
    if cmd.get("markers") == []:
        del cmd["markers"]
    return Parsed(cmd, rule.id, rule.grammar, clause, rule.chains)


def _run_together(grammar: Grammar, matcher: Matcher, clause: str) -> list[Parsed] | None:
    """``clause`` read as commands said back to back ("land take off"), or None.

    Only for a clause no rule matches whole (the caller's case), of at most
    ``MAX_RUN_WORDS`` words, split into at most ``MAX_RUN_COMMANDS`` commands that each stand
    alone (:func:`_stands_alone`). When two splits read differently ("fly forward | 2 meters
    left" against another) the clause is ambiguous and stays not understood: the dialog asks
    rather than guesses.
    """
    words = clause.split()
    if len(words) < 2 or len(words) > MAX_RUN_WORDS:
        return None
    readings = {
        tuple(repr(sorted(p.command.items())) for p in reading): reading
        for reading in _splits(grammar, matcher, words, MAX_RUN_COMMANDS)
    }
    return next(iter(readings.values())) if len(readings) == 1 else None


def _splits(grammar: Grammar, matcher: Matcher, words: list[str], parts: int) -> list[list[Parsed]]:
    """Every way to read ``words`` as 2..``parts`` stand-alone commands in a row."""
    out: list[list[Parsed]] = []
    for cut in range(1, len(words)):
        head = _command(grammar, matcher, " ".join(words[:cut]))
        if head is None or not _stands_alone(head):
            continue
        tail = _command(grammar, matcher, " ".join(words[cut:]))
        if tail is not None and _stands_alone(tail):
            out.append([head, tail])
        if parts > 2:
            out.extend([head, *more] for more in _splits(grammar, matcher, words[cut:], parts - 1))
    return out


def _stands_alone(parsed: Parsed) -> bool:
    """Whether a part of a run-together clause is a command in its own right: not a lone word
    that fills a slot ("left", "up": it more likely belongs to its neighbour), nor a part that
    starts with a number ("2 meters left" is the end of "fly forward 2 meters left"), nor a
    command of a grammar marked chain="no" in rules.xml (questions and dialog: "help me what
    you see", a mishearing of "tell me what you see", is not help + describe)."""
    words = parsed.text.split()
    if words[0][0].isdigit() or not parsed.chains:
        return False
    return len(words) > 1 or len(parsed.command) == 1


class NLU:
    """The language understander: a grammar directory, reloadable without a restart.

    Thread-safe: a reload swaps one reference; a parse uses whichever grammar it started with.
    """

    def __init__(self, grammar_dir: Path | str = DEFAULT_GRAMMAR_DIR) -> None:
        """Raises: GrammarError (file, line, rule) if the grammar cannot be loaded."""
        self._dir = Path(grammar_dir)
        grammar = load_grammar(self._dir)
        self._compiled = _Compiled.build(grammar)
        self._lock = threading.Lock()
        self.last_error: GrammarError | None = None

    @property
    def grammar(self) -> Grammar:
        return self._compiled.grammar

    @property
    def directory(self) -> Path:
        return self._dir

    def reload(self) -> Grammar:
        """Load the grammar files again; on failure keep the last good grammar and re-raise.

        Raises:
            GrammarError: the files on disk are unusable (the previous grammar stays active).
        """
        with self._lock:
            try:
                grammar = load_grammar(self._dir)
                compiled = _Compiled.build(grammar)
            except GrammarError as exc:
                self.last_error = exc
                raise
            self._compiled = compiled
            self.last_error = None
            return grammar

    def active_grammars(self, state: str | None) -> list[str]:
        """Names of the grammars active in ``state`` (UnknownStateError if not in states.xml)."""
        g = self._compiled.grammar
        active = g.active(state)
        return [name for name in g.grammars if name in active]

    def normalise(self, text: str) -> str:
        return self._compiled.norm.normalise(text)

    def parse(self, text: str, state: str | None = None) -> Interpretation:
        """Understand ``text`` with the grammars active in ``state`` (all if None).

        Raises:
            UnknownStateError: ``state`` is not in states.xml.
        """
        compiled = self._compiled
        grammar = compiled.grammar
        matcher = grammar.matcher(grammar.active(state))
        if not isinstance(text, str) or len(text) > MAX_UTTERANCE_CHARS:
            return Interpretation(str(text)[:80], "")
        norm = compiled.norm
        s = norm.normalise(text)
        parts = norm.split.split(s)
        pieces = [p.strip() for p in parts[0::2]][:MAX_PIECES]
        seps = parts[1::2]
        parsed: list[Parsed] = []
        unparsed: list[str] = []
        n = len(pieces)
        memo: dict[tuple[int, int], Parsed | None] = {}
        leads = [norm.lead.sub("", p) if p else p for p in pieces]

        def attempt(i: int, j: int) -> Parsed | None:
            """Pieces i..j-1 joined (commas dropped, other separators kept) as one clause."""
            if (i, j) not in memo:
                if j == i + 1:
                    memo[i, j] = _command(grammar, matcher, leads[i]) if leads[i] else None
                    return memo[i, j]
                clause = pieces[i]
                for k in range(i + 1, j):
                    sep = seps[k - 1]
                    clause = (
                        f"{clause} {pieces[k]}" if sep == "," else f"{clause} {sep} {pieces[k]}"
                    )
                clause = norm.lead.sub("", " ".join(clause.split()))
                memo[i, j] = _command(grammar, matcher, clause) if clause else None
            return memo[i, j]

        i = 0
        while i < n:
            if not pieces[i]:
                i += 1
                continue
            first = leads[i]
            hit = attempt(i, i + 1)
            end = i + 1
            if hit is None:
                # "fly forward, 2 meters": pieces that mean nothing alone belong together
                if i + 1 < n:
                    hit = attempt(i, i + 2)
                    end = i + 2
            else:
                # A longer run may still be one command: a piece that means nothing alone
                # completes this one, and a rule that contains "and"/"then" itself ("patrol
                # between 2 and 4", "come down and land") takes the longest run it matches.
                spans = matcher.may_span(hit.text)
                while end < min(n, i + MAX_WINDOW) and (spans or attempt(end, end + 1) is None):
                    longer = attempt(i, end + 1)
                    if longer is None:
                        break
                    hit, end = longer, end + 1
            if hit is not None:
                parsed.append(hit)
                i = end
                continue
            run = _run_together(grammar, matcher, first) if first else None
            if run:
                parsed.extend(run)
            elif first:
                unparsed.append(first)
            i += 1
        return Interpretation(text, s, tuple(parsed), tuple(unparsed))

    def answer(self, text: str) -> Answer | None:
        """ "yes" or "no" when all of ``text`` is one of the phrases of mappings.xml's ``ANSWER``
        set ("Yes.", "that's right", "nope"), else None: the answers to the dialog's "Did you
        say …?" (server/dialog/confirm.py). Answers are not commands: ``parse`` reads "yes" as a
        filler word, so "yes, take off" is a take-off."""
        phrases = self._compiled.grammar.sets.get(ANSWER_SET)
        if phrases is None or not isinstance(text, str) or len(text) > MAX_UTTERANCE_CHARS:
            return None
        # A phone keyboard types "That’s right" with a curly apostrophe: read as the NLU does.
        plain = text.lower().translate(_APOSTROPHES).replace("'", "")
        said = " ".join(_NOT_ANSWER_CHAR.sub(" ", plain).split())
        label = phrases.labels.get(said)
        if label == "yes":
            return "yes"
        if label == "no":
            return "no"
        return None

    def interpret(self, text: str, state: str | None = None) -> list[Command]:
        """The commands of ``text`` in spoken order; ``[]`` when nothing is understood.

        Raises:
            UnknownStateError: ``state`` is not in states.xml (a KeyError).
        """
        return self.parse(text, state).commands


@functools.lru_cache(maxsize=4)
def default_nlu(grammar_dir: str = str(DEFAULT_GRAMMAR_DIR)) -> NLU:
    """A shared NLU over ``grammar_dir`` (the project's grammars/ by default)."""
    return NLU(grammar_dir)


def interpret(text: str, state: str | None = None) -> list[Command]:
    """Module-level shortcut: :meth:`NLU.interpret` with the project's grammars."""
    return default_nlu().interpret(text, state)


__all__ = ["NLU", "Command", "Interpretation", "Parsed", "default_nlu", "interpret"]
