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

from server.captioner.references import Mention, SceneItem, mentions, salient_groups


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
