"""Snapping a transcript to a sentence the grammars accept (grammar-guided recognition, step 2).

Whisper writes what it heard as ordinary English ("fly to Marco free"); the NLU only accepts
what its grammars describe. When the NLU does not understand every piece of the transcript, the
words of the pieces it missed are replaced by near words of the grammars' vocabulary, nearest
first, until the NLU understands the whole sentence:

* nearness of two words is the mean of their normalised Levenshtein distance on letters and on
  Metaphone keys (Lawrence Philips, 1990; jellyfish's implementation), so "free" is near
  "three" and "Marco" near "marker" though they share few letters;
* a word may also be dropped (an inserted "uh", a breath read as a word);
* candidate sentences are tried in order of total cost (k-best enumeration over the product of
  per-word options), at most ``max_attempts`` NLU parses, so the time is bounded.

The total cost is the snap distance; the recogniser's confidence is multiplied by
``exp(-distance)``, so a transcript that had to be bent far enough falls under the dialog
manager's threshold and the operator is asked to repeat (Settings.confidence_threshold).

A snap is a guess: the recogniser reads it back ("Did you say …?"), never flies it as heard
(server.speech.recognizer.doubt). Two guesses are not even offered, since one "yes" would fly
them:

* an emergency (motors cut): a sentence with more emergencies than the transcript as heard is
  no candidate ("Y'all left by 30 degrees" is not "kill left by 30 degrees");
* the opposite direction: an edit that turns a heard direction word into its opposite
  ("ascend" into "descend"), or bends away a heard direction word in a sentence that then flies
  the opposite way ("climb down" into "climb 10"), makes no candidate.
"""

from __future__ import annotations

import functools
import heapq
import json
import math
from dataclasses import dataclass, field, replace
from typing import Any

import jellyfish
import numpy as np
from rapidfuzz.distance import Levenshtein
from rapidfuzz.process import cdist

from server.language.nlu import NLU, Interpretation
from server.speech.vocabulary import Vocabulary
from server.tasks.objects import KNOWN_KINDS

Command = dict[str, Any]
# The word sets of mappings.xml whose labels are directions (a move's, a turn's or a climb's).
DIRECTION_SETS = (
    "DIRECTION", "SIDE", "ROTATION", "UP_VERB", "DOWN_VERB", "FORWARD_VERB", "BACK_VERB",
)  # fmt: skip
_OPPOSITE = {
    "up": "down",
    "down": "up",
    "left": "right",
    "right": "left",
    "forward": "backward",
    "backward": "forward",
}
# Words of actions that move the drone one way without a direction slot.
_ACTION_SENSES = {"land": "down", "landing": "down"}
_ACTION_DIRECTION = {"land": "down", "takeoff": "up"}
# Margin (in snap-cost units, one unit ~ one word replaced by an unrelated one) at which a
# runner-up reading leaves a snap 1 - 1/e of its confidence: a runner-up 0.02 further (a
# letter) leaves 0.33, 0.1 further 0.86, 0.2 further 0.98. Chosen on bench/speech.py's 72-clip
# subset: 0.25 also gated right snaps ("side one meter downward", runner-up 0.22 further).
MARGIN_SCALE = 0.05


@dataclass(frozen=True)
class Snapped:
    """The sentence handed to the NLU and how far it is from what was heard."""

    heard: str  # the transcript
    text: str  # what the NLU read (normalised form), equal to the normalised transcript if no edit
    distance: float  # sum of word edit costs; 0 when the transcript was understood as heard
    edits: tuple[tuple[str, str], ...] = ()  # (heard word, used word); used "" = dropped
    commands: list[Command] = field(default_factory=list)
    complete: bool = False  # every piece of ``text`` understood
    # How much further the nearest sentence meaning something else is (runner-up cost minus
    # ``distance``); inf when none was found within the budget, or when nothing was bent.
    margin: float = math.inf

    @property
    def whole_as_heard(self) -> bool:
        """The grammars read the transcript whole without a single edit."""
        return self.complete and self.distance == 0.0 and bool(self.commands)

    @property
    def factor(self) -> float:
        """What the recogniser's confidence is multiplied by: exp(-distance), times
        1 - exp(-margin / MARGIN_SCALE) when a different command was nearly as near.

        A snap that had to choose between two readings almost equally far from what was heard
        ("climb" vs "land" for a garbled verb) is a guess; the margin factor pushes such a guess
        under the dialog manager's threshold so the operator is asked to repeat instead of a
        wrong command being flown (bench/speech.py counts wrong commands executed).
        """
        gate = 1.0 if math.isinf(self.margin) else 1.0 - math.exp(-self.margin / MARGIN_SCALE)
        return math.exp(-self.distance) * gate


class Snapper:
    """Snaps transcripts to the grammars of ``nlu`` (thread-safe: state is read-only)."""

    def __init__(
        self,
        nlu: NLU,
        vocab: Vocabulary,
        *,
        neighbours: int = 12,
        max_word_distance: float = 0.55,
        drop_cost: float = 0.75,
        max_attempts: int = 400,
        runner_up_attempts: int = 120,
    ) -> None:
        self.nlu = nlu
        self.vocab = vocab
        self.k = neighbours
        self.max_word_distance = max_word_distance
        self.drop_cost = drop_cost
        self.max_attempts = max_attempts
        self.runner_up_attempts = runner_up_attempts
        self._words = sorted(w for w in vocab.words if len(w) > 1)
        self._keys = [_key(w) for w in self._words]
        self._near = functools.lru_cache(maxsize=4096)(self._nearest)
        self._senses = _senses(nlu)

    def nearest(self, word: str) -> tuple[tuple[str, float], ...]:
        """Up to ``neighbours`` vocabulary words near ``word`` (nearest first), with cost."""
        return self._near(word)

    def _nearest(self, word: str) -> tuple[tuple[str, float], ...]:
        if not word.isalpha():
            return ()
        letters = cdist([word], self._words, scorer=Levenshtein.normalized_distance)[0]
        keys = cdist([_key(word)], self._keys, scorer=Levenshtein.normalized_distance)[0]
        cost = 0.5 * letters + 0.5 * keys
        order = np.argsort(cost, kind="stable")[: self.k + 1]
        return tuple(
            (self._words[i], float(cost[i]))
            for i in order
            if self._words[i] != word and cost[i] <= self.max_word_distance
        )[: self.k]

    def snap(self, text: str, state: str | None = None) -> Snapped:
        """The cheapest sentence near ``text`` that the NLU understands completely.

        When none is found within ``max_attempts`` parses, the transcript as heard (with
        whatever the NLU understood of it, possibly nothing) and distance 0 is returned: the
        dialog manager then says what it did not understand.
        """
        first = self.nlu.parse(text, state)
        heard = Snapped(text, first.normalised, 0.0, (), first.commands, _complete(first))
        if heard.complete or not first.normalised:
            return heard
        emergencies = _emergencies(first.commands)
        tokens = first.normalised.split()
        positions = _positions(tokens, first.unparsed + _unknown_objects(first))
        options: list[list[tuple[str, float]]] = []
        for i in positions:
            opts = [(tokens[i], 0.0), *self.nearest(tokens[i]), ("", self.drop_cost)]
            options.append(opts)
        best: Snapped | None = None
        budget = self.max_attempts
        for cost, choice in _k_best(options, self.max_attempts + self.runner_up_attempts):
            if cost == 0.0:
                continue
            budget -= 1
            if budget < 0 and best is None:
                break
            if best is not None and budget < -self.runner_up_attempts:
                break
            words = list(tokens)
            edits = []
            for pos, (i, c) in enumerate(zip(positions, choice, strict=True)):
                used = options[pos][c][0]
                if c:
                    edits.append((tokens[i], used))
                words[i] = used
            sentence = " ".join(w for w in words if w)
            if not sentence:
                continue
            interp = self.nlu.parse(sentence, state)
            if not _complete(interp):
                continue
            if not self._allowed(edits, interp.commands, emergencies):
                continue  # an emergency or the opposite way: never a reading
            if best is None:
                best = Snapped(
                    text, interp.normalised, cost, tuple(edits), interp.commands, complete=True
                )
                budget = min(budget, 0)  # from here on, runner_up_attempts more parses at most
            elif same_commands(interp.commands, best.commands):
                continue
            else:
                return replace(best, margin=cost - best.distance)
        return best if best is not None else heard

    def sense(self, word: str) -> frozenset[str]:
        """The directions ``word`` means in the grammars (empty for most words)."""
        return self._senses.get(word, frozenset())

    def _allowed(
        self, edits: list[tuple[str, str]], commands: list[Command], emergencies: int
    ) -> bool:
        """False when the edits make a sentence a snap may never make: more emergencies than
        heard, or a heard direction turned into its opposite."""
        if _emergencies(commands) > emergencies:
            return False
        flown = {d for c in commands if (d := direction(c)) is not None}
        for heard, used in edits:
            # "ascend" -> "descend"; "climb down" -> "climb 10" (the heard "down" bent away)
            lost = {o for d in self.sense(heard) if (o := _OPPOSITE.get(d)) is not None}
            if lost & (self.sense(used) | flown):
                return False
        return True


def opposite(direction: str) -> str | None:
    """The opposite of a direction label (up/down, left/right, forward/backward), else None."""
    return _OPPOSITE.get(direction)


def _senses(nlu: NLU) -> dict[str, frozenset[str]]:
    """Each single word of the direction sets (and "land") -> the directions it means."""
    out: dict[str, set[str]] = {w: {d} for w, d in _ACTION_SENSES.items()}
    for name in DIRECTION_SETS:
        ws = nlu.grammar.sets.get(name)
        for word, label in ws.labels.items() if ws else ():
            if " " not in word and label in _OPPOSITE:
                out.setdefault(word, set()).add(label)
    return {w: frozenset(d) for w, d in out.items()}


def direction(command: Command) -> str | None:
    """Which way a command flies the drone, when it has one way."""
    way = command.get("direction")
    if isinstance(way, str):
        return way
    return _ACTION_DIRECTION.get(str(command.get("action")))


def _emergencies(commands: list[Command]) -> int:
    return sum(1 for c in commands if c.get("action") == "emergency")


def _key(word: str) -> str:
    """Metaphone key with "th" (Metaphone's '0') read as "f": Whisper and speakers front it
    ("three" heard as "free")."""
    return (jellyfish.metaphone(word) or word).replace("0", "F")


def same_commands(a: list[Command], b: list[Command]) -> bool:
    """Whether two command lists would fly the same (key order aside)."""
    return json.dumps(a, sort_keys=True, default=str) == json.dumps(b, sort_keys=True, default=str)


def _complete(interp: Interpretation) -> bool:
    """Every piece understood, and no target that names a thing no world holds: the NLU
    passes any words as an ``object`` ("fly to Marco free") so the dialog can say what it
    does not know, but for a transcript that is a mishearing to snap, not a sentence."""
    return bool(interp.parsed) and not interp.unparsed and not _unknown_objects(interp)


def _unknown_objects(interp: Interpretation) -> tuple[str, ...]:
    """The words the NLU took for a target no world holds (``goto {object: "marco free"}``)."""
    return tuple(
        str(c["object"])
        for c in interp.commands
        if "object" in c and str(c["object"]) not in KNOWN_KINDS
    )


def _positions(tokens: list[str], unparsed: tuple[str, ...]) -> list[int]:
    """Indices of the tokens of the pieces the NLU did not understand (all when not found)."""
    out: list[int] = []
    start = 0
    for piece in unparsed:
        words = piece.split()
        for j in range(start, len(tokens) - len(words) + 1):
            if tokens[j : j + len(words)] == words:
                out.extend(range(j, j + len(words)))
                start = j + len(words)
                break
        else:
            return list(range(len(tokens)))
    return out or list(range(len(tokens)))


def _k_best(
    options: list[list[tuple[str, float]]], limit: int
) -> list[tuple[float, tuple[int, ...]]]:
    """The ``limit`` cheapest choices (one option index per position), cheapest first.

    Options of each position must be sorted by cost except the last (drop); they are sorted
    here. Standard lazy best-first expansion: from a choice, bump one position to its next
    option; a seen-set avoids duplicates.
    """
    for opts in options:
        opts.sort(key=lambda o: o[1])
    if not options:
        return []
    start = tuple(0 for _ in options)
    heap: list[tuple[float, tuple[int, ...]]] = [(0.0, start)]
    seen = {start}
    out: list[tuple[float, tuple[int, ...]]] = []
    while heap and len(out) < limit:
        cost, choice = heapq.heappop(heap)
        out.append((cost, choice))
        for pos, c in enumerate(choice):
            if c + 1 < len(options[pos]):
                nxt = (*choice[:pos], c + 1, *choice[pos + 1 :])
                if nxt not in seen:
                    seen.add(nxt)
                    delta = options[pos][c + 1][1] - options[pos][c][1]
                    heapq.heappush(heap, (cost + delta, nxt))
    return out
