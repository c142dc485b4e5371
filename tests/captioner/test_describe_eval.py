"""The description scorer (bench/describe.py) and its held-out frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drone.sim.world import COLOURS, OBJECT_KINDS
from server.captioner.eval import Said, TruthItem, recall_by_kind, said, score_descriptions
from server.captioner.evalset import SEED_BASE, sample

KINDS = (*sorted(OBJECT_KINDS), "marker")


def _said(text: str) -> list[Said]:
    return said(text, KINDS, list(COLOURS))


def test_said_reads_kinds_colours_sides_and_marker_ids() -> None:
    assert _said("I see a brown door ahead, an orange person on the right and marker 4 ahead.") == [
        Said("door", "brown", "ahead"),
        Said("person", "orange", "right"),
        Said("marker", None, "ahead", 4),
    ]
    assert _said(
        "There is a light blue window far off on the left. Markers 4, 5 and 7 in view."
    ) == [
        Said("window", "light blue", "left"),
        Said("marker", None, None, 4),
        Said("marker", None, None, 5),
        Said("marker", None, None, 7),
    ]
    assert _said("a marker close on the left and something red ahead") == [
        Said("marker", None, "left", None),
        Said(None, "red", "ahead"),
    ]
    assert _said("Nothing in view.") == []


def _t(
    kind: str, colour: str | None, side: str = "ahead", area: float = 0.05, mid: int | None = None
) -> TruthItem:
    return TruthItem(kind, colour, side, area, mid, area >= (0.005 if kind == "marker" else 0.012))


def test_scores_count_absent_things_wrong_colours_and_missed_kinds() -> None:
    truth = [
        [_t("person", "orange", "right"), _t("door", "brown"), _t("marker", None, "left", 0.01, 3)],
        [_t("tree", "green")],
    ]
    texts = [
        "a pink person close on the right and a blue door far ahead. Marker 3 in view.",
        "a green door far off on the right and a marker close on the left",
    ]
    r = score_descriptions(texts, truth, KINDS, list(COLOURS))
    assert r.kind_precision == pytest.approx(2 / 3)  # person, door right; door outdoors wrong
    assert r.kind_recall == pytest.approx(2 / 3)  # person, door named; tree missed
    assert r.colour_accuracy == 0.0  # pink person, blue door (the outdoor door is absent)
    assert r.named_but_absent == pytest.approx(2 / 5)  # the outdoor door and marker
    assert r.frames_with_absent == pytest.approx(1 / 2)
    assert r.marker_with_id == pytest.approx(1 / 2)
    assert r.marker_id_correct == 1.0 and r.marker_recall == 1.0
    assert recall_by_kind(r) == {"tree": (0, 1), "door": (1, 1), "person": (1, 1)}
    assert r.counts["absent:door"] == 1  # the outdoor one

    right = [
        "an orange person on the right, a brown door ahead and marker 3 on the left.",
        "a green tree ahead.",
    ]
    r = score_descriptions(right, truth, KINDS, list(COLOURS))
    assert (r.kind_precision, r.kind_recall, r.colour_accuracy) == (1.0, 1.0, 1.0)
    assert r.named_but_absent == 0.0 and r.marker_with_id == 1.0


def test_score_refuses_mismatched_lengths() -> None:
    with pytest.raises(ValueError):
        score_descriptions(["a"], [], KINDS, list(COLOURS))


def test_held_out_frames_are_deterministic_and_cover_both_worlds() -> None:
    a, b = sample(SEED_BASE), sample(SEED_BASE)
    assert np.array_equal(a.frame, b.frame) and a.truth == b.truth and a.pose == b.pose
    four = [sample(SEED_BASE + i) for i in range(4)]
    assert [(s.world, s.variant) for s in four] == [
        ("indoor", "world"),
        ("outdoor", "world"),
        ("indoor", "random"),
        ("outdoor", "random"),
    ]
    assert all(s.frame.shape == (360, 640, 3) for s in four)
    assert all(math.isfinite(v) for s in four for v in s.pose)
