"""Load and compile the three XML grammar files (states, rules, mappings) with defusedxml.

The result is an immutable :class:`Grammar`: expanded rule patterns, word sets with their labels,
the active grammars of each dialog state, and a cache of compiled matchers (per set of active
grammars, the rules dispatched by the first word of a clause, so a clause is tried only against
the few rules that can start with that word).
"""

from __future__ import annotations

import re
import threading
import warnings
import xml.parsers.expat
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element, ParseError

import defusedxml.ElementTree as DET

try:  # Python >= 3.11
    import re._parser as _sre_parser
except ImportError:  # pragma: no cover
    import sre_parse as _sre_parser  # type: ignore[no-redef,unused-ignore]
from defusedxml import DefusedXmlException

from server.language.errors import (
    DuplicateRuleError,
    GrammarError,
    GrammarSchemaError,
    GrammarSyntaxError,
    InvalidRegexError,
    UnknownGrammarError,
    UnknownSetError,
    UnknownStateError,
)

STATES_FILE = "states.xml"
RULES_FILE = "rules.xml"
MAPPINGS_FILE = "mappings.xml"
MAX_FILE_BYTES = 1 << 20  # a grammar is hand-written; anything bigger is a mistake

_SET_REF = re.compile(r"\{([A-Z][A-Z0-9_]*)\}")
_GROUP_DEF = re.compile(r"\(\?P<([A-Za-z_][A-Za-z0-9_]*)>")
_GROUP_REF = re.compile(r"\(\?P=([A-Za-z_][A-Za-z0-9_]*)\)")
_NUMBER = re.compile(r"\d+(?:\.\d+)?")
_INT = re.compile(r"\d+")
SLOT_TYPES = ("label", "quantity", "int", "int_list", "int_range", "text")
MAX_RANGE = 100  # "1 through 1000000" must not build a million-element list


@dataclass(frozen=True)
class WordSet:
    """A named set of mappings.xml: words -> label (and an optional numeric value)."""

    name: str
    regex: str  # a non-capturing alternation, longest words first
    labels: dict[str, str]
    values: dict[str, float]
    line: int


@dataclass(frozen=True)
class Slot:
    """How one named group of a rule becomes a command slot."""

    name: str
    group: str
    type: str
    set: str | None = None  # label lookup (type label, or int via ORDINAL)
    units: str | None = None  # unit set of a quantity


@dataclass(frozen=True)
class Rule:
    id: str
    grammar: str
    action: str
    priority: int
    pattern: str  # sets expanded, groups not yet prefixed
    slots: tuple[Slot, ...]
    consts: tuple[tuple[str, Any], ...]
    line: int
    order: int
    spans: bool = False  # the pattern contains a SPLIT word ("and", "then"): may span pieces
    # Its grammar's chain="no": a question or dialog command, never read out of commands said
    # back to back with no separator (server.language.nlu, "land take off").
    chains: bool = True


@dataclass(frozen=True)
class StateSpec:
    name: str
    grammars: tuple[str, ...]
    refuse: str


Candidate = tuple[re.Pattern[str], Rule, tuple[tuple[Slot, str], ...]]


@dataclass(frozen=True)
class Matcher:
    """The active rules, dispatched by the first word of a clause.

    A clause starting with "climb" is tried only against the rules whose pattern can begin with
    "climb" (computed once from the parsed regex by :func:`first_tokens`), in priority order.
    Each rule keeps its own compiled regex: ``re`` then rejects a non-matching clause in a few
    hundred nanoseconds using the pattern's literal prefix, which one big alternation loses
    (bench/nlu.py measures both).
    """

    rules: tuple[tuple[Rule, frozenset[str] | None], ...]  # None: may start with anything
    known: frozenset[str]
    compiled: dict[str, re.Pattern[str]]
    _by_key: dict[str, tuple[Candidate, ...]] = field(
        default_factory=dict, compare=False, repr=False
    )
    _spans: dict[str, bool] = field(default_factory=dict, compare=False, repr=False)

    def may_span(self, clause: str) -> bool:
        """Whether a rule that can start like ``clause`` contains "and"/"then" itself."""
        space = clause.find(" ")
        key = token_key(clause if space < 0 else clause[:space])
        found = self._spans.get(key)
        if found is None:
            found = any(c[1].spans for c in self.candidates(clause))
            if len(self._spans) < 4096:
                self._spans[key] = found
        return found

    def lookup(self, key: str) -> tuple[Candidate, ...]:
        if key not in self.known:
            key = ""  # a word no rule starts with: only the rules that may start with anything
        found = self._by_key.get(key)
        if found is None:
            found = tuple(
                (self.compiled[r.id], r, tuple((sl, sl.group) for sl in r.slots))
                for r, fs in self.rules
                if fs is None or key in fs
            )
            self._by_key[key] = found
        return found

    def candidates(self, clause: str) -> tuple[Candidate, ...]:
        space = clause.find(" ")
        return self.lookup(token_key(clause if space < 0 else clause[:space]))

    def fullmatch(
        self, clause: str
    ) -> tuple[re.Match[str], Rule, tuple[tuple[Slot, str], ...]] | None:
        """The highest-priority rule matching all of ``clause``, with its match."""
        if not clause:
            return None
        for regex, rule, slots in self.candidates(clause):
            m = regex.fullmatch(clause)
            if m is not None:
                return m, rule, slots
        return None


@dataclass(frozen=True)
class Grammar:
    """An immutable, validated grammar. Build it with :func:`load_grammar`."""

    directory: Path
    sets: dict[str, WordSet]
    rules: tuple[Rule, ...]
    grammars: tuple[str, ...]
    states: dict[str, StateSpec]
    _cache: dict[frozenset[str], Matcher] = field(default_factory=dict, repr=False, compare=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def active(self, state: str | None) -> frozenset[str]:
        """The grammars active in ``state`` (every grammar when ``state`` is None).

        Raises:
            UnknownStateError: states.xml does not list ``state``.
        """
        if state is None:
            return frozenset(self.grammars)
        spec = self.states.get(state)
        if spec is None:
            raise UnknownStateError(
                f"unknown dialog state {state!r} (known: {sorted(self.states)})"
            )
        return frozenset(spec.grammars)

    def grammar_of(self, rule_id: str) -> str:
        for rule in self.rules:
            if rule.id == rule_id:
                return rule.grammar
        raise KeyError(rule_id)

    def matcher(self, grammars: frozenset[str]) -> Matcher:
        """The compiled alternation for ``grammars`` (built once, then cached)."""
        found = self._cache.get(grammars)
        if found is not None:
            return found
        with self._lock:
            found = self._cache.get(grammars)
            if found is None:
                found = _compile_matcher([r for r in self.rules if r.grammar in grammars])
                self._cache[grammars] = found
        return found

    def word_set(self, name: str) -> WordSet:
        return self.sets[name]


def compile_strict(pattern: str) -> re.Pattern[str]:
    """``re.compile``, but syntax Python warns will change meaning (``[[``) is an error too.

    Raises:
        re.error: invalid, or ambiguous (the FutureWarning's text as the message).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)
        try:
            return re.compile(pattern)
        except FutureWarning as warning:
            raise re.error(f"ambiguous syntax: {warning}") from None


def _compile_matcher(rules: list[Rule]) -> Matcher:
    firsts = tuple((r, first_tokens(r.pattern)) for r in rules)
    known = frozenset(t for _r, fs in firsts if fs for t in fs)
    return Matcher(firsts, known, {r.id: re.compile(r.pattern) for r in rules})


_DIGIT_RUN = re.compile(r"\d+")
_FIRST_CAP = 20000


class _Unknown(Exception):
    """A regex construct the first-token analysis does not model."""


def token_key(token: str) -> str:
    """The dispatch key of a clause's first word: digit runs become '#' ("180" -> "#")."""
    return _DIGIT_RUN.sub("#", token)


def first_tokens(pattern: str) -> frozenset[str] | None:
    """Every first word (as :func:`token_key`) a match of ``pattern`` can start with.

    Computed from the parsed regular expression (``re._parser``) by following it up to the
    first space. None when it cannot tell (an unmodelled construct, an empty match, an
    unbounded word): such a rule is tried for every clause, which is always safe.
    """
    try:
        parsed = _sre_parser.parse(pattern)
        prefixes = _seq(list(parsed))
    except (_Unknown, RecursionError, ValueError, TypeError):
        return None
    if any(p == "" for p, _closed in prefixes):
        return None
    return frozenset(p for p, _closed in prefixes)


def _join(a: str, b: str) -> str:
    s = a + b
    return s.replace("##", "#") if "##" in s else s


def _seq(items: list[Any]) -> set[tuple[str, bool]]:
    acc: set[tuple[str, bool]] = {("", False)}
    for op, av in items:
        if all(closed for _p, closed in acc):
            break
        item = _item(op, av)
        nxt: set[tuple[str, bool]] = set()
        for p, closed in acc:
            if closed:
                nxt.add((p, True))
            else:
                nxt.update((_join(p, q), c) for q, c in item)
        if len(nxt) > _FIRST_CAP:
            raise _Unknown("too many")
        acc = nxt
    return acc


def _char(ch: str) -> tuple[str, bool]:
    if ch == " ":
        return ("", True)
    return ("#" if ch.isdigit() else ch, False)


def _item(op: Any, av: Any) -> set[tuple[str, bool]]:
    name = str(op)
    if name == "LITERAL":
        return {_char(chr(av))}
    if name == "IN":
        out: set[tuple[str, bool]] = set()
        for o, a in av:
            oname = str(o)
            if oname == "LITERAL":
                out.add(_char(chr(a)))
            elif oname == "CATEGORY" and str(a) == "CATEGORY_DIGIT":
                out.add(("#", False))
            elif oname == "RANGE" and a[1] - a[0] < 256:
                out.update(_char(chr(c)) for c in range(a[0], a[1] + 1))
            else:
                raise _Unknown(oname)
        return out
    if name == "BRANCH":
        res: set[tuple[str, bool]] = set()
        for sub in av[1]:
            res |= _seq(list(sub))
        return res
    if name == "SUBPATTERN":
        return _seq(list(av[3]))
    if name == "ATOMIC_GROUP":
        return _seq(list(av))
    if name in ("MAX_REPEAT", "MIN_REPEAT", "POSSESSIVE_REPEAT"):
        lo, hi, body = av
        once = _seq(list(body))
        total: set[tuple[str, bool]] = {("", False)} if lo == 0 else set()
        cur = once
        for k in range(1, 6):
            if k >= lo:
                before = len(total)
                total |= cur
                if k > lo and len(total) == before:
                    return total
            if k >= hi:
                return total
            cur = {
                (_join(p, q), c) if not closed else (p, True)
                for p, closed in cur
                for q, c in (once if not closed else {("", True)})
            }
        raise _Unknown("unbounded word")
    if name in ("AT", "ASSERT", "ASSERT_NOT"):
        return {("", False)}
    raise _Unknown(name)


def trie_regex(words: Iterable[str]) -> str:
    """A regex matching exactly ``words``, factored as a character trie.

    Python's ``re`` tries alternatives one by one; ``(?:go|got|going)`` as ``go(?:t|ing)?`` fails
    fast on the first character, which makes a 200-word set several times cheaper to scan.
    Longer words are tried first (greedy), shorter ones on backtracking, as longest-first order.
    """
    trie: dict[str, Any] = {}
    for w in words:
        if not w:
            continue
        node = trie
        for ch in w:
            node = node.setdefault(ch, {})
        node[""] = {}

    def emit(node: dict[str, Any]) -> str:
        ends = "" in node
        branches = [re.escape(ch) + emit(child) for ch, child in sorted(node.items()) if ch]
        if not branches:
            return ""
        body = branches[0] if len(branches) == 1 else "(?:" + "|".join(branches) + ")"
        if ends:
            return f"(?:{body})?" if len(branches) == 1 else f"{body}?"
        return body

    return emit(trie) if trie else "(?!)"


# -- XML reading ----------------------------------------------------------------------------------


def _read_xml(path: Path) -> tuple[Element, dict[Element, int]]:
    """Parse ``path`` safely; return the root and each element's line number."""
    name = path.name
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise GrammarSyntaxError(f"cannot read: {exc.strerror or exc}", file=name) from exc
    if len(data) > MAX_FILE_BYTES:
        raise GrammarSyntaxError(f"file is larger than {MAX_FILE_BYTES} bytes", file=name)
    try:
        root = DET.fromstring(data, forbid_dtd=True)
    except ParseError as exc:
        line = exc.position[0] if getattr(exc, "position", None) else None
        raise GrammarSyntaxError(f"malformed XML: {exc}", file=name, line=line) from exc
    except DefusedXmlException as exc:
        raise GrammarSyntaxError(f"refused XML feature: {exc}", file=name) from exc
    # ElementTree keeps no line numbers; a second expat pass over the same (already vetted)
    # bytes sees the start tags in the same document order as root.iter().
    lines: list[int] = []
    parser = xml.parsers.expat.ParserCreate()
    parser.StartElementHandler = lambda _n, _a: lines.append(parser.CurrentLineNumber)
    parser.Parse(data, True)
    return root, dict(zip(root.iter(), lines, strict=False))


def _attr(
    el: Element, key: str, file: str, lines: dict[Element, int], rule: str | None = None
) -> str:
    value = el.get(key)
    if value is None or not value.strip():
        raise GrammarSchemaError(
            f"<{el.tag}> needs a {key!r} attribute", file=file, line=lines.get(el), rule=rule
        )
    return value.strip()


# -- mappings.xml ---------------------------------------------------------------------------------


def _load_sets(path: Path) -> dict[str, WordSet]:  # noqa: C901
    """The word sets of one ``<mappings>`` file, each checked as it is read.

    Complexity: one check per element and attribute of the file's schema, each raising a
    :class:`GrammarSchemaError` that names the file and line."""
    file = path.name
    root, lines = _read_xml(path)
    if root.tag != "mappings":
        raise GrammarSchemaError("root element must be <mappings>", file=file, line=lines.get(root))
    raw: dict[str, tuple[list[str], dict[str, str], dict[str, float], int]] = {}
    for s in root:
        if s.tag != "set":
            raise GrammarSchemaError(f"unexpected <{s.tag}>", file=file, line=lines.get(s))
        name = _attr(s, "name", file, lines)
        if not re.fullmatch(r"[A-Z][A-Z0-9_]*", name):
            raise GrammarSchemaError(
                f"set name {name!r} must be upper case (A-Z, 0-9, _)", file=file, line=lines.get(s)
            )
        if name in raw:
            raise GrammarSchemaError(f"set {name} is defined twice", file=file, line=lines.get(s))
        alts: list[str] = []
        labels: dict[str, str] = {}
        values: dict[str, float] = {}
        words: list[str] = []
        for item in s:
            if item.tag == "pattern":
                alts.append((item.text or "").strip())
            elif item.tag == "item":
                label = item.get("label", "").strip()
                value_text = item.get("value")
                value: float | None = None
                if value_text is not None:
                    try:
                        value = float(value_text)
                    except ValueError as exc:
                        raise GrammarSchemaError(
                            f"value {value_text!r} of set {name} is not a number",
                            file=file,
                            line=lines.get(item),
                        ) from exc
                for w in (item.text or "").split(","):
                    word = " ".join(w.lower().split())
                    if not word:
                        continue
                    words.append(word)
                    labels.setdefault(word, label)
                    if value is not None:
                        values.setdefault(word, value)
            else:
                raise GrammarSchemaError(
                    f"unexpected <{item.tag}> in set {name}", file=file, line=lines.get(item)
                )
        if words:
            alts.append(trie_regex(words))
        raw[name] = (alts, labels, values, lines.get(s, 0))
    # expand {OTHER} inside set patterns (cycles are an error)
    expanded: dict[str, str] = {}

    def expand(name: str, stack: tuple[str, ...]) -> str:
        if name in expanded:
            return expanded[name]
        alts, _l, _v, line = raw[name]

        def sub(m: re.Match[str]) -> str:
            ref = m.group(1)
            if ref not in raw:
                raise UnknownSetError(
                    f"set {name} uses unknown set {{{ref}}}", file=file, line=line
                )
            if ref in stack:
                raise UnknownSetError(
                    f"sets refer to each other: {' -> '.join((*stack, ref))}", file=file, line=line
                )
            return expand(ref, (*stack, ref))

        body = "|".join(_SET_REF.sub(sub, a) for a in alts) or "(?!)"
        expanded[name] = f"(?:{body})"
        return expanded[name]

    sets: dict[str, WordSet] = {}
    for name, (_alts, labels, values, line) in raw.items():
        regex = expand(name, (name,))
        try:
            compile_strict(regex)
        except re.error as exc:
            raise InvalidRegexError(f"set {name}: {exc}", file=file, line=line) from exc
        sets[name] = WordSet(name, regex, labels, values, line)
    return sets


# -- rules.xml ------------------------------------------------------------------------------------


def _const_value(text: str) -> Any:
    if _INT.fullmatch(text):
        return int(text)
    if _NUMBER.fullmatch(text):
        return float(text)
    return text


def _load_rules(path: Path, sets: dict[str, WordSet]) -> tuple[tuple[Rule, ...], tuple[str, ...]]:
    file = path.name
    root, lines = _read_xml(path)
    if root.tag != "rules":
        raise GrammarSchemaError("root element must be <rules>", file=file, line=lines.get(root))
    rules: list[Rule] = []
    seen: dict[str, int] = {}
    grammars: list[str] = []
    for g in root:
        if g.tag != "grammar":
            raise GrammarSchemaError(f"unexpected <{g.tag}>", file=file, line=lines.get(g))
        gname = _attr(g, "name", file, lines)
        if gname in grammars:
            raise GrammarSchemaError(
                f"grammar {gname} is defined twice", file=file, line=lines.get(g)
            )
        grammars.append(gname)
        chain = g.get("chain", "yes").strip()
        if chain not in ("yes", "no"):
            raise GrammarSchemaError(
                f'grammar {gname}: chain must be "yes" or "no", not {chain!r}',
                file=file,
                line=lines.get(g),
            )
        for r in g:
            if r.tag != "rule":
                raise GrammarSchemaError(f"unexpected <{r.tag}>", file=file, line=lines.get(r))
            rule = _load_rule(r, gname, file, lines, sets, seen, len(rules))
            rules.append(replace(rule, chains=chain == "yes"))
    rules.sort(key=lambda x: (-x.priority, x.order))
    if "SPLIT" in sets:
        split = re.compile(r"(?<![a-z])(?:" + sets["SPLIT"].regex + r")(?![a-z])")
        rules = [
            replace(r, spans=split.search(r.pattern.replace("\\ ", " ")) is not None) for r in rules
        ]
    return tuple(rules), tuple(grammars)


def _load_rule(
    r: Element,
    grammar: str,
    file: str,
    lines: dict[Element, int],
    sets: dict[str, WordSet],
    seen: dict[str, int],
    order: int,
) -> Rule:
    line = lines.get(r, 0)
    rid = _attr(r, "id", file, lines)
    if rid in seen:
        raise DuplicateRuleError(
            f"duplicate rule id (first defined on line {seen[rid]})", file=file, line=line, rule=rid
        )
    seen[rid] = line
    action = _attr(r, "action", file, lines, rid)
    try:
        priority = int(r.get("priority", "0"))
    except ValueError as exc:
        raise GrammarSchemaError(
            f"priority {r.get('priority')!r} is not an integer", file=file, line=line, rule=rid
        ) from exc
    patterns = [p for p in r if p.tag == "pattern"]
    if len(patterns) != 1:
        raise GrammarSchemaError(
            "a rule needs exactly one <pattern>", file=file, line=line, rule=rid
        )
    pat_el = patterns[0]
    pat_line = lines.get(pat_el, line)
    source = " ".join((pat_el.text or "").split())
    if not source:
        raise GrammarSchemaError("empty <pattern>", file=file, line=pat_line, rule=rid)

    def sub(m: re.Match[str]) -> str:
        ref = m.group(1)
        if ref not in sets:
            raise UnknownSetError(f"unknown set {{{ref}}}", file=file, line=pat_line, rule=rid)
        return sets[ref].regex

    pattern = _SET_REF.sub(sub, source)
    try:
        compiled = compile_strict(pattern)
    except re.error as exc:
        raise InvalidRegexError(
            f"invalid regex: {exc}", file=file, line=pat_line, rule=rid
        ) from exc
    slots: list[Slot] = []
    consts: list[tuple[str, Any]] = []
    for el in r:
        if el.tag == "pattern":
            continue
        el_line = lines.get(el, line)
        if el.tag == "const":
            consts.append(
                (
                    _attr(el, "name", file, lines, rid),
                    _const_value(_attr(el, "value", file, lines, rid)),
                )
            )
            continue
        if el.tag != "slot":
            raise GrammarSchemaError(f"unexpected <{el.tag}>", file=file, line=el_line, rule=rid)
        name = _attr(el, "name", file, lines, rid)
        group = el.get("group", name)
        set_name = el.get("set")
        units = el.get("units")
        stype = el.get("type") or ("quantity" if units else "label" if set_name else "text")
        if stype not in SLOT_TYPES:
            raise GrammarSchemaError(
                f"slot {name}: unknown type {stype!r} (one of {', '.join(SLOT_TYPES)})",
                file=file,
                line=el_line,
                rule=rid,
            )
        for ref in (set_name, units):
            if ref is not None and ref not in sets:
                raise UnknownSetError(
                    f"slot {name}: unknown set {ref}", file=file, line=el_line, rule=rid
                )
        if stype == "label" and set_name is None:
            raise GrammarSchemaError(
                f"slot {name}: a label needs set=", file=file, line=el_line, rule=rid
            )
        if group not in compiled.groupindex:
            raise GrammarSchemaError(
                f"slot {name}: the pattern has no group (?P<{group}>...)",
                file=file,
                line=el_line,
                rule=rid,
            )
        slots.append(Slot(name, group, stype, set_name, units))
    return Rule(rid, grammar, action, priority, pattern, tuple(slots), tuple(consts), line, order)


# -- states.xml -----------------------------------------------------------------------------------


def _load_states(path: Path, grammars: Iterable[str]) -> dict[str, StateSpec]:
    file = path.name
    known = set(grammars)
    root, lines = _read_xml(path)
    if root.tag != "states":
        raise GrammarSchemaError("root element must be <states>", file=file, line=lines.get(root))
    states: dict[str, StateSpec] = {}
    for s in root:
        if s.tag != "state":
            raise GrammarSchemaError(f"unexpected <{s.tag}>", file=file, line=lines.get(s))
        name = _attr(s, "name", file, lines)
        if name in states:
            raise GrammarSchemaError(f"state {name} is listed twice", file=file, line=lines.get(s))
        refs: list[str] = []
        for g in s:
            if g.tag != "grammar":
                raise GrammarSchemaError(f"unexpected <{g.tag}>", file=file, line=lines.get(g))
            ref = _attr(g, "ref", file, lines)
            if ref not in known:
                raise UnknownGrammarError(
                    f"state {name} uses unknown grammar {ref!r}", file=file, line=lines.get(g)
                )
            refs.append(ref)
        states[name] = StateSpec(name, tuple(refs), s.get("refuse", "").strip())
    return states


def load_grammar(directory: Path | str) -> Grammar:
    """Load states.xml, rules.xml and mappings.xml from ``directory``.

    Raises:
        GrammarError: (a subclass naming file, line and rule) if any file is unusable.
    """
    d = Path(directory)
    sets = _load_sets(d / MAPPINGS_FILE)
    rules, grammars = _load_rules(d / RULES_FILE, sets)
    states = _load_states(d / STATES_FILE, grammars)
    grammar = Grammar(d, sets, rules, grammars, states)
    grammar.matcher(frozenset(grammars))  # compile the full alternation now: fail at load
    return grammar


__all__ = [
    "Grammar",
    "GrammarError",
    "Matcher",
    "Rule",
    "Slot",
    "StateSpec",
    "WordSet",
    "load_grammar",
]
