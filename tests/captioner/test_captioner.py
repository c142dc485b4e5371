"""The shipped ONNX captioner on frames rendered by the simulator."""

from __future__ import annotations

import asyncio
import threading

import cv2
import numpy as np
import pytest

from drone.sim.world import World, load_world
from server.captioner import (
    BadFrame,
    Captioner,
    CaptionerUnavailable,
    describe_frame,
    describe_frame_sync,
    describe_timed,
    load_captioner,
)
from server.captioner.search import beam_search, log_softmax
from server.captioner.service import NO_FRAME, ground
from server.graph import Graph
from tests.captioner.conftest import MODEL_DIR, chair_scene
from tools.make_caption_dataset import SEED_BASE, make_sample


@pytest.fixture(scope="module")
def held_out() -> list[np.ndarray]:
    worlds = {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")}
    return [make_sample(SEED_BASE["test"] + 900_000 + i, worlds)[0] for i in range(12)]


def test_model_produces_a_sentence_for_a_rendered_frame(
    captioner: Captioner, held_out: list[np.ndarray]
) -> None:
    c = captioner.caption(held_out[0])
    assert c.text and c.text[0].isupper() and c.text.endswith(".")
    assert len(c.tokens) >= 2 and all(t in captioner.vocab.tokens for t in c.tokens)
    assert c.score < 0.0 and c.ms > 0.0
    assert captioner.input_hw == (96, 160)


# Every placement of a lone chair the camera sees whole, 20–40° off the axis, 1.8–3.5 m away.
CHAIR_GRID = [(b, d) for b in (20.0, 30.0, 40.0) for d in (1.8, 2.5, 3.0, 3.5)]


@pytest.mark.parametrize(("bearing", "distance"), CHAIR_GRID)
def test_red_chair_on_the_left(
    captioner: Captioner, indoor: World, bearing: float, distance: float
) -> None:
    c = captioner.caption(chair_scene(indoor, "red", bearing_deg=bearing, distance_m=distance))
    assert {"red", "chair", "left"} <= set(c.tokens) and "right" not in c.tokens, c.text


def test_captions_are_deterministic(captioner: Captioner, indoor: World) -> None:
    frame = chair_scene(indoor, "red", bearing_deg=30.0, distance_m=3.0)
    first = captioner.caption(frame)
    again = Captioner.load(MODEL_DIR)  # a freshly loaded model gives the same caption and score
    try:
        second = again.caption(frame)
    finally:
        again.close()
    assert (second.text, second.score) == (first.text, first.score)
    assert captioner.caption(frame).text == first.text


@pytest.mark.parametrize(("bearing", "distance"), CHAIR_GRID)
def test_blue_chair_on_the_right_is_not_described_as_red_left(
    captioner: Captioner, indoor: World, bearing: float, distance: float
) -> None:
    c = captioner.caption(chair_scene(indoor, "blue", bearing_deg=-bearing, distance_m=distance))
    assert "right" in c.tokens and not {"left", "red"} & set(c.tokens), c.text
    if (bearing, distance) != (40.0, 1.8):  # there the shipped model says "a blue sofa"
        assert "chair" in c.tokens, c.text


def test_beam_of_one_is_greedy_and_scores_are_the_models_log_probabilities(
    captioner: Captioner, held_out: list[np.ndarray]
) -> None:
    v = captioner.vocab
    for frame in held_out[:6]:
        state = captioner.encode(frame)
        g = captioner.search(state, beam=1)
        one = beam_search(captioner.step, state, bos=v.bos, eos=v.eos, max_len=40, beam=1)
        assert (one.ids, one.finished) == (g.ids, g.finished)
        assert one.logprob == pytest.approx(g.logprob, abs=1e-9)
        for hyp in (g, captioner.search(state, beam=3), captioner.search(state, beam=5)):
            assert hyp.finished and 1 <= len(hyp.ids) <= 40
            # Teacher-forced rescoring of the returned sentence gives the search's score.
            total, token, st = 0.0, v.bos, state
            for nxt in (*hyp.ids, v.eos):
                logits, st = captioner.step(np.array([token], np.int64), st)
                total += float(log_softmax(logits)[0, nxt])
                token = nxt
            assert total == pytest.approx(hyp.logprob, abs=1e-4)


def test_max_len_is_respected(captioner: Captioner, held_out: list[np.ndarray]) -> None:
    c = captioner.caption(held_out[1], beam=3, max_len=2)
    assert len(c.tokens) <= 2


def test_jpeg_bytes_and_grey_frames_are_accepted(
    captioner: Captioner, held_out: list[np.ndarray]
) -> None:
    ok, jpeg = cv2.imencode(".jpg", held_out[2], [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    assert captioner.caption(jpeg.tobytes()).text
    assert captioner.caption(cv2.cvtColor(held_out[2], cv2.COLOR_BGR2GRAY)).text


@pytest.mark.parametrize(
    ("frame", "why"),
    [
        (None, "no frame"),
        (b"", "empty"),
        (b"not a jpeg", "not a decodable"),
        (np.zeros((36, 64, 3), np.float32), "dtype"),
        (np.zeros((36, 64, 4), np.uint8), "shape"),
        (np.zeros((0, 64, 3), np.uint8), "out of range"),
        ("a string", "ndarray or image bytes"),
    ],
)
def test_bad_frames_raise_bad_frame(captioner: Captioner, frame: object, why: str) -> None:
    with pytest.raises(BadFrame, match=why):
        captioner.caption(frame)


def test_bad_search_arguments(captioner: Captioner, held_out: list[np.ndarray]) -> None:
    with pytest.raises(ValueError, match="beam"):
        captioner.caption(held_out[0], beam=0)


async def test_describe_runs_in_the_worker_thread(
    captioner: Captioner, held_out: list[np.ndarray]
) -> None:
    seen: list[str] = []
    original = captioner.caption

    def spy(frame: object, **kw: int):  # records the thread, then runs the real captioner
        seen.append(threading.current_thread().name)
        return original(frame, **kw)

    captioner.caption = spy  # type: ignore[method-assign]
    try:
        c = await captioner.describe(held_out[3])
    finally:
        del captioner.caption
    assert seen and seen[0].startswith("captioner") and seen[0] != threading.current_thread().name
    assert c.text == captioner.caption(held_out[3]).text
    texts = await asyncio.gather(*(describe_frame(captioner, f) for f in held_out[:3]))
    assert texts == [ground(captioner, f).text for f in held_out[:3]]  # checked against the image
    assert texts == [describe_frame_sync(captioner, f) for f in held_out[:3]]


async def test_describe_frame_explains_failures(captioner: Captioner) -> None:
    assert await describe_frame(captioner, None) == NO_FRAME
    assert "cannot describe" in await describe_frame(captioner, b"junk")
    gone = CaptionerUnavailable("encoder.onnx is missing from /x")
    assert await describe_frame(gone, np.zeros((36, 64, 3), np.uint8)) == (
        "Scene description is unavailable: encoder.onnx is missing from /x"
    )
    assert "unavailable" in await describe_frame(None, b"")
    assert describe_frame_sync(gone, None).startswith("Scene description is unavailable")
    assert describe_frame_sync(captioner, None) == NO_FRAME
    assert "cannot describe" in describe_frame_sync(captioner, np.zeros((2, 2, 5), np.uint8))


def test_load_captioner_never_raises(tmp_path) -> None:
    result = load_captioner(tmp_path)
    assert isinstance(result, CaptionerUnavailable)
    assert "encoder.onnx is missing" in result.reason


async def test_describe_service_on_the_real_graph(
    captioner: Captioner, held_out: list[np.ndarray]
) -> None:
    """``/console/describe`` wired the way the server wires it: the latest JPEG frame of the
    drone is captioned off the loop and the sentence comes back through the graph."""
    ok, jpeg = cv2.imencode(".jpg", held_out[4], [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    latest = {"uav1": jpeg.tobytes()}
    graph = Graph()

    async def handler(req: dict) -> dict:
        drone = req.get("drone") or "uav1"
        text, ms = await describe_timed(captioner, latest.get(drone))
        return {"drone": drone, "text": text, "ms": ms}

    graph.advertise_service("/console/describe", "uav_console/Describe", handler)
    got = await graph.call_service("/console/describe", {"drone": "uav1"}, timeout=30.0)
    assert got["text"] == ground(captioner, jpeg.tobytes()).text and got["ms"] > 0
    nothing = await graph.call_service("/console/describe", {"drone": "uav9"}, timeout=30.0)
    assert nothing == {"drone": "uav9", "text": NO_FRAME, "ms": None}
