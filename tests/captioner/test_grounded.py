"""Descriptions name only what the image shows, in its colours, markers with their ids.

The scenes of the operator's report ("What do you see?" indoors: "a pink person close on the
right and a blue door far ahead" for an orange person and a brown door), rendered by the
simulator and described by the shipped model; the simulator's truth is read only here, to
check the sentence.
"""

from __future__ import annotations

import math
import re
import types
from pathlib import Path

import numpy as np
import pytest

from drone.sim.camera import Renderer
from drone.sim.world import COLOURS, OBJECT_KINDS, World, load_world
from server.captioner import Captioner, CaptionerUnavailable, describe_frame_sync
from server.captioner.eval import Said, TruthItem, said, score_descriptions
from server.captioner.evalset import SEED_BASE, TUNING_SEED_BASE, TruthLabel, sample
from server.captioner.grounding import SeenMarker, Thing, ground_marker_ids, ground_objects
from server.captioner.markers import MarkerDetector
from server.captioner.scene import KINDS as SCENE_KINDS
from server.captioner.scene import Region
from server.captioner.service import ground
from tests.captioner.conftest import MODEL_DIR

KINDS = (*sorted(OBJECT_KINDS), "marker")
Pose = tuple[float, float, float, float, float, float]


@pytest.fixture(scope="module")
def outdoor() -> World:
    return load_world("outdoor")


def _named(text: str) -> list[Said]:
    return list(said(text, KINDS, list(COLOURS)))


def _untrue(text: str, truth: tuple[TruthLabel, ...]) -> list[Said]:
    """What ``text`` names that is not in view, in another colour, or a marker without id."""
    objects = {(t.kind, t.colour) for t in truth if t.kind != "marker"}
    ids = {t.marker_id for t in truth if t.kind == "marker"}
    bad = []
    for s in _named(text):
        if s.kind == "marker":
            ok = s.marker_id is not None and s.marker_id in ids
        elif s.kind is None:
            ok = any(c == s.colour for _, c in objects)
        else:
            ok = any(k == s.kind and (s.colour is None or c == s.colour) for k, c in objects)
        if not ok:
            bad.append(s)
    return bad


def _check_true(text: str, renderer: Renderer, pose: Pose) -> None:
    """Every kind named is in view, with the colour named; every marker id named is in view."""
    visible = renderer.visible(pose)
    objects = {(v.kind, v.colour) for v in visible if v.kind != "marker"}
    kinds = {k for k, _ in objects}
    ids = {v.marker_id for v in visible if v.kind == "marker"}
    for s in _named(text):
        if s.kind == "marker":
            assert s.marker_id is not None, f"marker without its id: {text!r}"
            assert s.marker_id in ids, f"marker {s.marker_id} is not in view: {text!r}"
        elif s.kind is not None:
            assert s.kind in kinds, f"no {s.kind} in view ({sorted(objects)}): {text!r}"
            if s.colour is not None:
                assert (s.kind, s.colour) in objects, f"wrong colour ({sorted(objects)}): {text!r}"


# Poses in the shipped room where the captioner alone said "a pink person close on the right"
# (the person is orange) and "a pink door far ahead" (the door is brown).
PERSON_AND_DOOR: list[Pose] = [
    (4.3, 2.94, 0.96, 0.0, 0.0, 0.0),
    (3.82, 3.33, 0.96, 0.0, 0.0, -0.16),
]


@pytest.mark.parametrize("pose", PERSON_AND_DOOR)
def test_indoor_person_and_door_in_their_own_colours(
    captioner: Captioner, indoor: World, pose: Pose
) -> None:
    renderer = Renderer(indoor, seed=1)
    frame = renderer.render(pose)
    raw = captioner.caption(frame).text
    assert "pink person" in raw or "pink door" in raw  # the report's mistake, reproduced
    text = describe_frame_sync(captioner, frame)
    _check_true(text, renderer, pose)
    named = {(s.kind, s.colour) for s in _named(text)}
    assert ("person", "orange") in named, text
    assert ("door", "brown") in named, text


# Held-out frames of the shipped field where the captioner alone names what is not there:
# "a blue car" (it is red) and "marker 2" (marker 0 is in view); "a yellow car" (a yellow box);
# "marker 0 close on the right" (markers 1 and 2 are in view).
OUTDOOR_SEEDS = (3000057, 3000073, 3000071)


@pytest.mark.parametrize("seed", OUTDOOR_SEEDS)
def test_outdoor_names_nothing_that_is_not_there(captioner: Captioner, seed: int) -> None:
    s = sample(seed)
    raw = captioner.caption(s.frame).text
    assert _untrue(raw, s.truth), raw  # the report's mistake, reproduced
    text = describe_frame_sync(captioner, s.frame)
    assert not _untrue(text, s.truth), text


def test_a_marker_is_named_with_the_detectors_id(captioner: Captioner, indoor: World) -> None:
    """1.5 m in front of marker 5: "marker 5", never "a marker" or another id."""
    marker = next(m for m in indoor.markers if m.id == 5)
    stand = marker.standoff(1.5)
    pose: Pose = (stand.x, stand.y, stand.z, 0.0, 0.0, stand.yaw_rad)
    renderer = Renderer(indoor, seed=2)
    frame = renderer.render(pose)
    assert [m.id for m in MarkerDetector().detect(frame)] == [5]
    text = describe_frame_sync(captioner, frame)
    assert re.search(r"\bmarker 5 ahead\b", text), text
    _check_true(text, renderer, pose)


def test_markers_the_vehicle_reports_are_named_too(captioner: Captioner, indoor: World) -> None:
    """A marker hidden from the frame's detector (e.g. under the tracking overlay) but reported
    by the vehicle's perception is named with its id, on its side."""
    frame = Renderer(indoor, seed=2).render((4.0, 3.0, 1.2, 0.0, 0.0, -math.pi / 2))
    assert 7 not in [m.id for m in MarkerDetector().detect(frame)]
    text = describe_frame_sync(captioner, frame, markers=[SeenMarker(7, 30.0)])
    assert "marker 7 on the left" in text, text


def test_an_empty_view_names_nothing(captioner: Captioner, outdoor: World) -> None:
    """Only sky and grass: nothing is named."""
    pose: Pose = (-10.0, 10.0, 2.0, 0.0, 0.0, math.pi)
    renderer = Renderer(outdoor, seed=4)
    assert not renderer.visible(pose, 0.0)
    text = describe_frame_sync(captioner, renderer.render(pose))
    assert _named(text) == [], text


def test_grounding_is_deterministic(captioner: Captioner, indoor: World) -> None:
    frame = Renderer(indoor, seed=1).render(PERSON_AND_DOOR[0])
    first = ground(captioner, frame)
    assert ground(captioner, frame.copy()).text == first.text
    assert first.ms > 0.0


def test_without_regions_json_the_caption_is_kept(tmp_path: Path, indoor: World) -> None:
    for name in ("encoder.onnx", "decoder.onnx", "vocab.json"):
        (tmp_path / name).write_bytes((MODEL_DIR / name).read_bytes())
    plain = Captioner.load(tmp_path)
    try:
        assert plain.regions is None
        frame = Renderer(indoor, seed=1).render(PERSON_AND_DOOR[0])
        seen = [m.seen() for m in MarkerDetector().detect(frame)]
        assert seen  # marker 5 is in view: its id comes from the detector
        expected = ground_marker_ids(plain.caption(frame).text, seen)
        assert describe_frame_sync(plain, frame) == expected
    finally:
        plain.close()


@pytest.mark.parametrize(
    ("content", "why"),
    [
        ("{not json", "regions.json is unusable"),
        ('{"format": "something else"}', "regions.json is unusable"),
        (
            '{"format": "uav-console-scene-regions/1", "kinds": ["none"], "features": 1}',
            "regions.json is unusable",
        ),
    ],
)
def test_a_broken_regions_file_makes_the_captioner_unavailable(
    tmp_path: Path, content: str, why: str
) -> None:
    for name in ("encoder.onnx", "decoder.onnx", "vocab.json"):
        (tmp_path / name).write_bytes((MODEL_DIR / name).read_bytes())
    (tmp_path / "regions.json").write_text(content)
    with pytest.raises(CaptionerUnavailable, match=why):
        Captioner.load(tmp_path)


def test_the_regions_file_is_checked_for_shapes(tmp_path: Path) -> None:
    import json

    data = json.loads((MODEL_DIR / "regions.json").read_text())
    data["w2"] = data["w2"][:-1]
    for name in ("encoder.onnx", "decoder.onnx", "vocab.json"):
        (tmp_path / name).write_bytes((MODEL_DIR / name).read_bytes())
    (tmp_path / "regions.json").write_text(json.dumps(data))
    with pytest.raises(CaptionerUnavailable, match="wrong shape"):
        Captioner.load(tmp_path)


def test_frames_of_another_size_are_described(captioner: Captioner, indoor: World) -> None:
    frame = Renderer(indoor, seed=1).render(PERSON_AND_DOOR[0])
    small = np.ascontiguousarray(frame[::2, ::2])
    text = describe_frame_sync(captioner, small)
    assert text.endswith(".")


class _Stack:
    """The parts of a drone stack ``Runtime.describe`` reads: the driver's latest frame and the
    markers the vehicle's perception sees."""

    def __init__(self, frame: np.ndarray | None, markers: list[SeenMarker]) -> None:
        self.driver = types.SimpleNamespace(latest_frame=frame)
        self._markers = markers

    def seen_markers(self) -> list[SeenMarker]:
        return self._markers


async def test_runtime_describe_grounds_the_latest_frame(
    captioner: Captioner, indoor: World
) -> None:
    from server.runtime import Runtime

    renderer = Renderer(indoor, seed=1)
    frame = renderer.render(PERSON_AND_DOOR[0])
    runtime = types.SimpleNamespace(
        drones={"uav1": _Stack(frame, []), "uav2": _Stack(None, [SeenMarker(3, 0.0)])},
        _captioner=captioner,
    )
    text, ms = await Runtime.describe(runtime, "uav1")  # type: ignore[arg-type]
    assert ms is not None and ms > 0.0
    assert text == ground(captioner, frame).text
    _check_true(text, renderer, PERSON_AND_DOOR[0])
    assert await Runtime.describe(runtime, "uav2") == (  # type: ignore[arg-type]
        "I have no camera image to describe yet.",
        None,
    )
    with pytest.raises(LookupError):
        await Runtime.describe(runtime, "uav9")  # type: ignore[arg-type]


def test_held_out_frames_name_less_that_is_false(captioner: Captioner) -> None:
    """60 held-out frames (both worlds): the grounded descriptions name fewer absent things and
    far fewer wrong colours than the captioner's sentences, and every marker with its id.
    (The full figures come from ``bench/describe.py``.)"""
    frames = [sample(SEED_BASE + i) for i in range(60)]
    truths = [
        [TruthItem(t.kind, t.colour, t.side, t.area, t.marker_id, t.mentionable) for t in s.truth]
        for s in frames
    ]
    detector = MarkerDetector()
    raw = [
        ground_marker_ids(
            captioner.caption(s.frame).text, [m.seen() for m in detector.detect(s.frame)]
        )
        for s in frames
    ]
    grounded = [describe_frame_sync(captioner, s.frame) for s in frames]
    before = score_descriptions(raw, truths, KINDS, list(COLOURS))
    after = score_descriptions(grounded, truths, KINDS, list(COLOURS))
    assert after.named_but_absent < before.named_but_absent, (before, after)
    assert after.colour_accuracy >= 0.9 > before.colour_accuracy, (before, after)
    assert after.kind_precision >= 0.9 and after.marker_with_id == 1.0, after


@pytest.mark.timeout(600)  # 60 frames rendered and described: slow on a loaded machine
def test_indoor_frames_name_the_salient_kinds(captioner: Captioner) -> None:
    """60 indoor frames of the tuning set (never the reported held-out set): the grounded
    descriptions name at least 80 % of the kinds a person would name first (white and grey
    furniture against the walls, chairs beside a table, objects cut by the frame's edge
    included; 75 % with the classifier trained without cluttered rooms), while naming almost
    nothing that is not there (the 2 % target is the held-out set's; here one mention in 60
    frames is 0.4 %)."""
    frames = [sample(TUNING_SEED_BASE + 2 * i) for i in range(60)]
    assert {s.world for s in frames} == {"indoor"}
    truths = [
        [TruthItem(t.kind, t.colour, t.side, t.area, t.marker_id, t.mentionable) for t in s.truth]
        for s in frames
    ]
    texts = [describe_frame_sync(captioner, s.frame) for s in frames]
    r = score_descriptions(texts, truths, KINDS, list(COLOURS))
    assert r.kind_recall >= 0.8, r
    assert r.kind_precision >= 0.9 and r.colour_accuracy >= 0.9, r
    assert r.named_but_absent <= 0.03, r


def _region(colour: str, side: str, area: float, **p: float) -> Region:
    """A region of the image with the classifier's probabilities ``p`` (the rest: none)."""
    probs = [p.get(k, 0.0) for k in SCENE_KINDS]
    probs[0] = 1.0 - sum(probs)
    return Region(colour, side, area, (0, 0, 10, 10), 0.0, (), tuple(probs))


def test_a_kind_the_captioner_puts_on_the_wrong_side_is_found_where_it_is() -> None:
    sofa = _region("grey", "left", 0.05, sofa=0.6, table=0.1)
    things = ground_objects("There is a pink sofa far off on the right.", [sofa])
    assert things == [Thing("sofa", "grey", "left", 0.05)]
    unsure = _region("grey", "left", 0.05, sofa=0.4, table=0.3)
    assert ground_objects("There is a pink sofa far off on the right.", [unsure]) == []


def test_regions_the_captioner_left_out_are_named_when_likely_shelves_when_sure() -> None:
    chair = _region("red", "ahead", 0.03, chair=0.55, table=0.2)
    shelf = _region("white", "left", 0.04, shelf=0.7, door=0.2)
    assert ground_objects("", [shelf, chair]) == [Thing("chair", "red", "ahead", 0.03)]
    sure = _region("white", "left", 0.04, shelf=0.85, door=0.1)
    assert [t.kind for t in ground_objects("", [sure, chair])] == ["shelf", "chair"]
    # as likely a sofa as a box (the yellow box beside the shipped room's door): not named
    either = _region("yellow", "right", 0.03, sofa=0.5, box=0.46)
    assert ground_objects("", [either]) == []
