"""Caption quality on held-out scenes: BLEU-4 and object-mention precision/recall/F1.

BLEU-4 is sacrebleu's corpus BLEU against all references of each image (Papineni et al. 2002).
CIDEr-D is not reported: the only package with it (pycocoevalcap) has had no release since 2020.

Object mentions (:func:`mention_scores`), micro-averaged over images:

* precision: named kinds that are really visible / named kinds;
* recall: salient kinds (those the references name, :func:`salient_groups`) that are named /
  salient kinds;
* the *attribute* variant counts (kind, colour, side, marker id) tuples instead of kinds.
"""

from __future__ import annotations

import statistics
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from server.captioner.references import (
    SIDE_WORDS,
    Mention,
    SceneItem,
    mentions,
    salient_groups,
)


@dataclass(frozen=True)
class PRF:
    precision: float
    recall: float
    f1: float


@dataclass(frozen=True)
class MentionScores:
    objects: PRF
    attributes: PRF


@dataclass(frozen=True)
class Report:
    """One system's scores on an evaluation set (``ms`` = per-image latency samples)."""

    name: str
    bleu4: float
    mentions: MentionScores
    ms: tuple[float, ...] = ()

    @property
    def median_ms(self) -> float:
        return statistics.median(self.ms) if self.ms else float("nan")


def _prf(tp_p: int, n_pred: int, tp_r: int, n_gold: int) -> PRF:
    p = tp_p / n_pred if n_pred else 1.0
    r = tp_r / n_gold if n_gold else 1.0
    f = 2 * p * r / (p + r) if p + r else 0.0
    return PRF(p, r, f)


def _key(m: Mention) -> tuple[object, ...]:
    return (m.kind, m.colour, m.side, m.marker_id)


def mention_scores(
    captions: Sequence[str],
    scenes: Sequence[Sequence[SceneItem]],
    kinds: Iterable[str],
    colours: Iterable[str],
    seen: Sequence[Sequence[SceneItem]] | None = None,
) -> MentionScores:
    """Micro-averaged object and attribute precision/recall/F1 of ``captions`` (see module doc).

    ``scenes`` are the items the references may name; ``seen`` (default: ``scenes``) everything
    really visible, however small, which a caption may name without being wrong.
    """
    seen = scenes if seen is None else seen
    if not len(captions) == len(scenes) == len(seen):
        raise ValueError(f"{len(captions)} captions for {len(scenes)}/{len(seen)} scenes")
    kinds, colours = list(kinds), list(colours)
    o = [0, 0, 0, 0]  # tp for precision, predicted, tp for recall, gold
    a = [0, 0, 0, 0]
    for caption, items, visible in zip(captions, scenes, seen, strict=True):
        said = mentions(caption, kinds, colours)
        groups = salient_groups(items)
        pred_k = {m.kind for m in said}
        seen_k = {i.kind for i in visible}
        gold_k = {g.kind for g in groups}
        o[0] += len(pred_k & seen_k)
        o[1] += len(pred_k)
        o[2] += len(pred_k & gold_k)
        o[3] += len(gold_k)
        pred_a = {_key(m) for m in said}
        seen_a = {
            (i.kind, i.colour, i.side, i.marker_id if i.kind == "marker" else None) for i in visible
        }
        gold_a = {(g.kind, g.colour, g.side, g.marker_id) for g in groups}
        a[0] += len(pred_a & seen_a)
        a[1] += len(pred_a)
        a[2] += len(pred_a & gold_a)
        a[3] += len(gold_a)
    return MentionScores(_prf(*o), _prf(*a))


def bleu4(captions: Sequence[str], references: Sequence[Sequence[str]]) -> float:
    """Corpus BLEU-4 (0–100) with every image's references (padded to equal count by repeats)."""
    import sacrebleu  # test/bench dependency only

    if len(captions) != len(references):
        raise ValueError(f"{len(captions)} captions for {len(references)} reference sets")
    width = max(len(r) for r in references)
    streams = [[refs[i % len(refs)].lower() for refs in references] for i in range(width)]
    hyps = [c.lower().rstrip(".") for c in captions]
    return float(sacrebleu.corpus_bleu(hyps, streams, tokenize="13a").score)


def most_frequent_caption(references: Iterable[Sequence[str]]) -> str:
    """The trivial baseline: the training caption seen most often (ties: alphabetical)."""
    counts = Counter(r for refs in references for r in refs)
    if not counts:
        raise ValueError("no training captions")
    return min(counts, key=lambda c: (-counts[c], c))


def evaluate(
    name: str,
    caption_fn: Callable[[int], tuple[str, float]],
    references: Sequence[Sequence[str]],
    scenes: Sequence[Sequence[SceneItem]],
    kinds: Iterable[str],
    colours: Iterable[str],
    seen: Sequence[Sequence[SceneItem]] | None = None,
) -> Report:
    """Score ``caption_fn(i) -> (caption, ms)`` over images ``0..n-1``."""
    out = [caption_fn(i) for i in range(len(references))]
    caps = [c for c, _ in out]
    return Report(
        name=name,
        bleu4=bleu4(caps, references),
        mentions=mention_scores(caps, scenes, kinds, colours, seen),
        ms=tuple(ms for _, ms in out),
    )


# -- descriptions against the simulator's truth (bench/describe.py) ----------------------------


@dataclass(frozen=True)
class Said:
    """One thing a description names: a kind (``marker`` included) or only a colour
    ("something brown"), with its colour, side and marker id when given."""

    kind: str | None
    colour: str | None = None
    side: str | None = None
    marker_id: int | None = None


def said(text: str, kinds: Iterable[str], colours: Iterable[str]) -> list[Said]:
    """Things named in ``text``: kind nouns (via :func:`mentions`), "something <colour>", and
    marker ids, including lists ("markers 3 and 5", "Markers 3, 5 and 7 in view")."""
    colours = list(colours)
    kinds = [k for k in kinds if k != "marker"]
    out: list[Said] = [
        Said(m.kind, m.colour, m.side) for m in mentions(text, kinds, colours) if m.kind != "marker"
    ]
    words = text.lower().replace(",", " , ").replace(".", " . ").split()
    phrases: list[list[str]] = [[]]
    for w in words:
        if w in ("and", ",", "."):
            phrases.append([])
        else:
            phrases[-1].append(w)
    in_list = False
    colour_words = sorted(colours, key=lambda c: -len(c.split()))
    for ph in phrases:
        if not ph:
            continue
        side = next((SIDE_WORDS[w] for w in ph if w in SIDE_WORDS), None)
        if in_list and ph[0].isdigit():
            out.append(Said("marker", None, side, int(ph[0])))
            continue
        in_list = False
        for i, w in enumerate(ph):
            if w in ("marker", "markers"):
                nxt = ph[i + 1] if i + 1 < len(ph) else ""
                if nxt.isdigit():
                    out.append(Said("marker", None, side, int(nxt)))
                    in_list = w == "markers"
                else:
                    out.append(Said("marker", None, side, None))
            elif w == "something":
                rest = ph[i + 1 :]
                colour = next(
                    (c for c in colour_words if rest[: len(c.split())] == c.split()), None
                )
                out.append(Said(None, colour, side))
    return out


@dataclass(frozen=True)
class TruthItem:
    """A visible thing as the scorer sees it (``server.captioner.evalset.TruthLabel`` fits)."""

    kind: str
    colour: str | None
    side: str
    area: float
    marker_id: int | None
    mentionable: bool


@dataclass(frozen=True)
class DescriptionScores:
    """Scores of descriptions against the truth, micro-averaged over frames.

    * kind precision: object kinds named that are visible (any size) / object kinds named;
    * kind recall: salient object kinds (among the three largest groups of mentionable things,
      the ones a person names first) that are named / salient object kinds;
    * colour accuracy: colour words on named things in view that some visible thing of that kind
      (for "something <colour>": any visible object) really has / such colour words;
    * named-but-absent: things named (kinds, "something <colour>", markers) of which nothing in
      view fits / things named; ``frames_with_absent``: share of descriptions with one or more;
    * markers: share of marker mentions with an id, share of those ids that are in view, and
      mentionable markers whose id is named / mentionable markers.

    ``counts`` holds the sums behind these, and per kind ``gold:<kind>`` (salient),
    ``gold_named:<kind>`` (salient and named) and ``absent:<kind>`` (named, none in view).
    """

    frames: int
    kind_precision: float
    kind_recall: float
    colour_accuracy: float
    named_but_absent: float
    frames_with_absent: float
    marker_with_id: float
    marker_id_correct: float
    marker_recall: float
    side_accuracy: float
    counts: dict[str, int]


def _ratio(a: int, b: int) -> float:
    return a / b if b else float("nan")


def recall_by_kind(scores: DescriptionScores) -> dict[str, tuple[int, int]]:
    """Salient object kinds named / salient, per kind (from ``scores.counts``), most missed
    first: which kinds a describer misses."""
    c = scores.counts
    kinds = [k.split(":", 1)[1] for k in c if k.startswith("gold:")]
    out = {k: (c.get(f"gold_named:{k}", 0), c[f"gold:{k}"]) for k in kinds}
    return dict(sorted(out.items(), key=lambda kv: (kv[1][0] - kv[1][1], kv[0])))


def score_descriptions(
    texts: Sequence[str],
    truths: Sequence[Sequence[TruthItem]],
    kinds: Iterable[str],
    colours: Iterable[str],
) -> DescriptionScores:
    """Score descriptions of frames against what each frame really shows (see the class doc)."""
    if len(texts) != len(truths):
        raise ValueError(f"{len(texts)} descriptions for {len(truths)} frames")
    kinds, colours = list(kinds), list(colours)
    c: Counter[str] = Counter()
    for text, truth in zip(texts, truths, strict=True):
        things = said(text, kinds, colours)
        objects = [t for t in truth if t.kind != "marker"]
        visible_kinds = {t.kind for t in objects}
        salient = salient_groups(
            [
                SceneItem(t.kind, t.colour, t.side, False, t.area, t.marker_id)  # type: ignore[arg-type]
                for t in truth
                if t.mentionable
            ]
        )
        gold = {g.kind for g in salient if g.kind != "marker"}
        named = {s.kind for s in things if s.kind not in (None, "marker")}
        c["kinds_named"] += len(named)
        c["kinds_named_visible"] += len(named & visible_kinds)
        c["kinds_gold"] += len(gold)
        c["kinds_gold_named"] += len(gold & named)
        for kind in gold:
            c[f"gold:{kind}"] += 1
            c[f"gold_named:{kind}"] += kind in named
        for kind in named - visible_kinds:
            c[f"absent:{kind}"] += 1
        absent_here = 0
        for s in things:
            c["mentions"] += 1
            if s.kind == "marker":
                ids = {t.marker_id for t in truth if t.kind == "marker"}
                c["marker_mentions"] += 1
                if s.marker_id is None:
                    ok = bool(ids)
                else:
                    c["marker_mentions_with_id"] += 1
                    ok = s.marker_id in ids
                    c["marker_ids_correct"] += ok
            elif s.kind is None:
                ok = s.colour is not None and any(t.colour == s.colour for t in objects)
                if s.colour is not None and objects:
                    c["colours_named"] += 1
                    c["colours_right"] += ok
            else:
                same = [t for t in objects if t.kind == s.kind]
                ok = bool(same)
                if same and s.colour is not None:
                    c["colours_named"] += 1
                    c["colours_right"] += any(t.colour == s.colour for t in same)
                if same and s.side is not None:
                    c["sides_named"] += 1
                    c["sides_right"] += any(t.side == s.side for t in same)
            if not ok:
                absent_here += 1
        c["absent"] += absent_here
        c["frames_with_absent"] += absent_here > 0
        gold_markers = {t.marker_id for t in truth if t.kind == "marker" and t.mentionable}
        named_ids = {s.marker_id for s in things if s.kind == "marker"}
        c["markers_gold"] += len(gold_markers)
        c["markers_gold_named"] += len(gold_markers & named_ids)
    return DescriptionScores(
        frames=len(texts),
        kind_precision=_ratio(c["kinds_named_visible"], c["kinds_named"]),
        kind_recall=_ratio(c["kinds_gold_named"], c["kinds_gold"]),
        colour_accuracy=_ratio(c["colours_right"], c["colours_named"]),
        named_but_absent=_ratio(c["absent"], c["mentions"]),
        frames_with_absent=_ratio(c["frames_with_absent"], len(texts)),
        marker_with_id=_ratio(c["marker_mentions_with_id"], c["marker_mentions"]),
        marker_id_correct=_ratio(c["marker_ids_correct"], c["marker_mentions_with_id"]),
        marker_recall=_ratio(c["markers_gold_named"], c["markers_gold"]),
        side_accuracy=_ratio(c["sides_right"], c["sides_named"]),
        counts=dict(c),
    )
