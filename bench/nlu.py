"""NLU throughput and accuracy.

Throughput: utterances per second over a few thousand generated sentences (seeded), median of
several runs, for the compiled grammar (dispatch by first word + one alternation) and for a
naive baseline measured in the same run: the same normalisation, then ``re.fullmatch`` of every
rule in priority order for each clause. Accuracy: exact match on tests/data/nlu_labelled.jsonl.

    python bench/nlu.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from server.language.nlu import NLU  # noqa: E402

TEMPLATES = [
    "go {dir} {n} meters",
    "move {dir} {n} feet",
    "fly {dir} {w} centimeters",
    "climb {w} meter",
    "turn {side} {a} degrees",
    "rotate {side}",
    "fly to marker {m}",
    "go to tag {w}",
    "patrol markers {m}, {m2} and {m3}",
    "take off",
    "land now",
    "stop",
    "what do you see",
    "how much battery is left",
    "where are you",
    "please take off and go to marker {m} then land",
    "uh drone, climb half a meter and then turn around",
    "cancel that",
    "status",
    "come back",
    "take off, go {dir} {n} meters, rotate {side} {a} degrees and then land",
    "blah blah blah",
]
DIRS = ["up", "down", "forward", "back", "left", "right"]
WORDS = ["one", "two", "three", "twenty five", "a hundred and eighty", "one and a half"]


def corpus(n: int, seed: int = 7) -> list[str]:
    r = random.Random(seed)
    out = []
    for _ in range(n):
        t = r.choice(TEMPLATES)
        out.append(
            t.format(
                dir=r.choice(DIRS),
                n=r.randint(1, 9),
                w=r.choice(WORDS),
                side=r.choice(["left", "right", "clockwise"]),
                a=r.choice([30, 45, 90]),
                m=r.randint(1, 9),
                m2=r.randint(1, 9),
                m3=r.randint(1, 9),
            )
        )
    return out


def rates(engines: dict[str, object], texts: list[str], runs: int) -> dict[str, float]:
    """Median utterances/s per engine; engines interleaved in each run (same machine load)."""
    got: dict[str, list[float]] = {name: [] for name in engines}
    for _ in range(runs):
        for name, fn in engines.items():
            t0 = time.perf_counter()
            for t in texts:
                fn(t)  # type: ignore[operator]
            got[name].append(len(texts) / (time.perf_counter() - t0))
    return {name: statistics.median(v) for name, v in got.items()}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    nlu = NLU()
    texts = corpus(1000 if args.quick else 4000)
    runs = 3 if args.quick else 7
    # Baseline: the same pipeline with a matcher that tries every rule, in priority order, with
    # re.fullmatch (each rule compiled once): the naive loop the first-word dispatch replaces.
    import re

    from server.language.grammar import Matcher

    g = nlu.grammar
    everything = frozenset(g.grammars)
    fast = g.matcher(everything)
    naive = Matcher(tuple((r, None) for r, _fs in fast.rules), frozenset(), dict(fast.compiled))
    naive_nlu = NLU()
    naive_nlu.grammar._cache[everything] = naive
    norm = nlu._compiled.norm
    clauses = [
        norm.lead.sub("", p.strip())
        for t in texts
        for p in norm.split.split(norm.normalise(t))[0::2]
    ]
    rx_all = [re.compile(r.pattern) for r, _fs in fast.rules]

    def naive_match(clause: str) -> bool:
        return any(rx.fullmatch(clause) for rx in rx_all)

    def dispatch_match(clause: str) -> bool:
        return fast.fullmatch(clause) is not None

    assert all(naive_nlu.interpret(t) == nlu.interpret(t) for t in texts[:300])
    whole = rates({"naive": naive_nlu.interpret, "interpret": nlu.interpret}, texts, runs)
    match = rates({"naive": naive_match, "dispatch": dispatch_match}, clauses, runs)
    rows = [
        json.loads(x)
        for x in (ROOT / "tests/data/nlu_labelled.jsonl").read_text().splitlines()
        if x
    ]
    ok = sum(nlu.interpret(r["text"]) == r["commands"] for r in rows)
    m_naive, m_fast = match["naive"], match["dispatch"]
    w_naive, w_fast = whole["naive"], whole["interpret"]
    table = [
        ("rule matching (normalised clauses)", "naive: re.fullmatch per rule", m_naive, 1.0),
        ("rule matching (normalised clauses)", "first-word dispatch", m_fast, m_fast / m_naive),
        ("interpret() whole utterances", "naive per-rule matcher", w_naive, 1.0),
        ("interpret() whole utterances", "first-word dispatch", w_fast, w_fast / w_naive),
    ]
    print(f"corpus: {len(texts)} generated utterances ({len(clauses)} clauses),")
    print(f"median of {runs} runs, one core, engines interleaved within each run")
    print()
    print("| what | engine | per second | ratio vs naive |")
    print("|---|---|---:|---:|")
    for what, engine, per_s, ratio in table:
        print(f"| {what} | {engine} | {per_s:,.0f} | {ratio:.2f} |")
    print()
    acc = ok / len(rows)
    print(f"accuracy on tests/data/nlu_labelled.jsonl: {ok}/{len(rows)} = {acc:.1%} exact match")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
