"""vocab.json handling, reference captions, and reading mentions back from captions."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.captioner.errors import CaptionerUnavailable
from server.captioner.eval import bleu4, mention_scores, most_frequent_caption
from server.captioner.references import (
    SIDES,
    Mention,
    SceneItem,
    mentions,
    plural,
    references,
    salient_groups,
)
from server.captioner.vocab import Vocab, detokenize, tokenize

KINDS = ["chair", "table", "door", "window", "person", "plant", "box", "shelf", "marker"]
COLOURS = ["red", "green", "blue", "light blue", "orange", "white"]

# -- vocab --------------------------------------------------------------------------------------


def test_vocab_round_trip(tmp_path: Path) -> None:
    v = Vocab.build(["red", "chair", "on", "the", "left"])
    v.save(tmp_path / "vocab.json")
    w = Vocab.load(tmp_path / "vocab.json")
    assert w == v and (w.pad, w.bos, w.eos, w.unk) == (0, 1, 2, 3)
    ids = w.encode("A red Chair, on the LEFT!")
    assert w.words([w.bos, *ids, w.eos, *ids]) == [
        "<unk>",
        "red",
        "chair",
        "<unk>",
        "on",
        "the",
        "left",
    ]


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        ('{"tokens": []}', "non-empty list"),
        ('{"tokens": ["<pad>", "<pad>"]}', "duplicates"),
        ('{"tokens": ["<pad>", "<bos>", "<eos>"]}', "unk"),
        ('{"tokens": ["a", 3]}', "non-empty list of strings"),
    ],
)
def test_bad_vocab_files_say_why(tmp_path: Path, content: str, reason: str) -> None:
    (tmp_path / "vocab.json").write_text(content)
    with pytest.raises(CaptionerUnavailable, match=reason):
        Vocab.load(tmp_path / "vocab.json")


def test_missing_vocab_file(tmp_path: Path) -> None:
    with pytest.raises(CaptionerUnavailable, match=r"vocab\.json is missing"):
        Vocab.load(tmp_path / "vocab.json")


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=20,
)


@settings(max_examples=200, deadline=None)
@given(st.one_of(json_values, st.fixed_dictionaries({"tokens": json_values})))
def test_arbitrary_json_loads_or_raises_unavailable(data: object) -> None:
    try:
        v = Vocab.from_json(data)
    except CaptionerUnavailable as exc:
        assert exc.reason
    else:
        assert len(v) >= 1 and max(v.pad, v.bos, v.eos, v.unk) < len(v)


def test_detokenize() -> None:
    assert detokenize(["i", "see", "a", "door"]) == "I see a door."
    assert detokenize([]) == ""
    assert tokenize("Marker 7, far ahead.") == ["marker", "7", ",", "far", "ahead"]
    assert detokenize(["a", "box", ",", "a", "door"]) == "A box, a door."


# -- references and mentions ------------------------------------------------------------------


def test_plurals() -> None:
    assert [plural(k) for k in ("chair", "person", "shelf", "box", "window")] == [
        "chairs",
        "people",
        "shelves",
        "boxes",
        "windows",
    ]


def test_canonical_caption_for_a_red_chair_on_the_left() -> None:
    items = [SceneItem("chair", "red", "left", True, 0.1)]
    refs = references(items, 5, seed=1)
    assert refs[0] == "there is a red chair close on the left"
    assert len(refs) == 5 and len(set(refs)) == 5
    assert all("red chair" in r and "left" in r for r in refs)


def test_groups_counts_and_markers() -> None:
    items = [
        SceneItem("chair", "blue", "right", False, 0.02),
        SceneItem("chair", "blue", "right", False, 0.03),
        SceneItem("marker", None, "ahead", True, 0.04, marker_id=7),
        SceneItem("plant", "green", "left", False, 0.001),
        SceneItem("door", "brown", "left", False, 0.0005),
    ]
    groups = salient_groups(items)
    assert [g.kind for g in groups] == ["chair", "marker", "plant"]  # door is the 4th: dropped
    assert references(items, 1, seed=0)[0] == (
        "there are two blue chairs far off on the right , marker 7 close ahead "
        "and a green plant far off on the left"
    )


def test_empty_scene() -> None:
    refs = references([], 5, seed=3)
    assert refs[0] == "nothing in view" and len(refs) == 5
    assert mentions(refs[0], KINDS, COLOURS) == []


items_st = st.lists(
    st.builds(
        SceneItem,
        kind=st.sampled_from(KINDS),
        colour=st.sampled_from(COLOURS),
        side=st.sampled_from(SIDES),
        near=st.booleans(),
        area=st.floats(0.0001, 0.5),
        marker_id=st.integers(0, 49),
    ).map(
        lambda i: (
            i
            if i.kind != "marker"
            else SceneItem("marker", None, i.side, i.near, i.area, i.marker_id)
        )
    ),
    max_size=6,
)


@settings(max_examples=150, deadline=None)
@given(items_st, st.integers(0, 1000))
def test_every_reference_reads_back_as_its_salient_groups(
    items: list[SceneItem], seed: int
) -> None:
    """The grammar and the mention parser agree: each reference names exactly the salient
    groups, with colour, side and marker id, so perfect captions score F1 = 1."""
    gold = {
        (g.kind, g.colour, g.side, g.marker_id if g.kind == "marker" else None)
        for g in salient_groups(items)
    }
    for ref in references(items, 4, seed):
        got = {(m.kind, m.colour, m.side, m.marker_id) for m in mentions(ref, KINDS, COLOURS)}
        assert got == gold, ref


def test_mentions_of_free_text() -> None:
    said = mentions("I see two light blue boxes on the left and a person ahead.", KINDS, COLOURS)
    assert said == [Mention("box", "light blue", "left"), Mention("person", None, "ahead")]


# -- scores -----------------------------------------------------------------------------------


def test_scores_perfect_captions_and_baseline() -> None:
    scenes = [
        [SceneItem("chair", "red", "left", True, 0.1)],
        [
            SceneItem("door", "white", "ahead", False, 0.2),
            SceneItem("plant", "green", "right", True, 0.05),
        ],
        [SceneItem("marker", None, "right", True, 0.03, marker_id=4)],
        [],
    ]
    refs = [references(s, 3, seed=i) for i, s in enumerate(scenes)]
    perfect = mention_scores([r[0] for r in refs], scenes, KINDS, COLOURS)
    assert perfect.objects.f1 == 1.0 and perfect.attributes.f1 == 1.0
    base = most_frequent_caption(refs)
    trivial = mention_scores([base] * len(scenes), scenes, KINDS, COLOURS)
    assert trivial.objects.f1 < 0.6
    assert bleu4([r[0] for r in refs], refs) == pytest.approx(100.0)
    assert bleu4([base] * len(scenes), refs) < 50.0
    wrong_side = mention_scores(["a red chair on the right", "", "", ""], scenes, KINDS, COLOURS)
    assert wrong_side.objects.precision == 1.0 and wrong_side.attributes.precision == 0.0


def test_vocab_json_written_by_build_is_plain_json(tmp_path: Path) -> None:
    Vocab.build(["a"]).save(tmp_path / "v.json")
    data = json.loads((tmp_path / "v.json").read_text())
    assert data["format"] == "uav-console-captioner-vocab/1" and data["tokens"][:2] == [
        "<pad>",
        "<bos>",
    ]
