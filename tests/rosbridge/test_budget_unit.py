"""Decoding budgets without sockets: the PNG header and pixel decoder, value counting, id
peeking (Hypothesis for each parser), the protocol's triage and the worker pool."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import itertools
import json
import multiprocessing
import struct
import threading
import zlib
from typing import Any

import cbor2
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.rosbridge import ops
from server.rosbridge.budget import (
    PNG_SIGNATURE,
    DecodeBudget,
    PngError,
    check_png_budget,
    count_values,
    json_values_bound,
    peek_id,
    png_header,
    png_text,
)
from server.rosbridge.decoder import InboundDecoder, work
from server.rosbridge.encode import png_encode
from server.rosbridge.errors import BudgetExceeded, DecoderBusy, FrameError
from server.rosbridge.inbound import DecodeRequest, run_decode
from server.rosbridge.protocol import BridgeProtocol

BUDGET = DecodeBudget()


def chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def png_of(width: int, height: int, raw: bytes, *, depth: int = 8, colour: int = 2) -> bytes:
    """A PNG with this IHDR and ``raw`` (already laid out in rows) as its one IDAT."""
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return (
        PNG_SIGNATURE
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


def statuses(p: BridgeProtocol) -> list[dict[str, Any]]:
    return [json.loads(f) for f in p.frames_to_send() if isinstance(f, str)]


# -- the PNG header ----------------------------------------------------------------------------
@given(st.binary(max_size=64))
def test_png_header_of_any_bytes_parses_or_raises_png_error(data: bytes) -> None:
    try:
        header = png_header(data)
    except PngError:
        return
    assert header.width > 0 and header.height > 0


@given(st.binary(max_size=64))
def test_png_header_after_a_signature_parses_or_raises_png_error(data: bytes) -> None:
    with contextlib.suppress(PngError):
        png_header(PNG_SIGNATURE + b"\0\0\0\x0dIHDR" + data)


@given(
    st.integers(1, 2**31 - 1),
    st.integers(1, 2**31 - 1),
    st.integers(1, 1 << 24),
    st.integers(1, 1 << 24),
)
def test_the_header_budget_refuses_exactly_what_is_over_it(
    width: int, height: int, max_pixels: int, max_bytes: int
) -> None:
    budget = DecodeBudget(max_png_pixels=max_pixels, max_png_bytes=max_bytes)
    header = png_header(png_of(width, height, b"")[:33])
    over = width * height > max_pixels or height * (1 + 3 * width) > max_bytes
    if over:
        with pytest.raises(BudgetExceeded, match=f"{width}×{height} pixels"):
            check_png_budget(header, budget)
    else:
        check_png_budget(header, budget)


def test_a_png_over_the_budget_is_refused_before_its_pixels_are_read() -> None:
    # The finding's image: 1 pixel wide, 16 MB of rows. Its IDAT here is not even zlib: the
    # refusal comes from the header alone.
    rows = (16 << 20) // 4
    ihdr = struct.pack(">IIBBBBB", 1, rows, 8, 2, 0, 0, 0)
    png = PNG_SIGNATURE + chunk(b"IHDR", ihdr) + chunk(b"IDAT", b"not zlib") + chunk(b"IEND", b"")
    with pytest.raises(BudgetExceeded, match="1×4194304 pixels"):
        png_text(png, BUDGET)


@pytest.mark.parametrize(
    ("depth", "colour"), [(16, 2), (8, 6), (8, 0), (1, 3)], ids=["16bit", "rgba", "grey", "pal"]
)
def test_only_8_bit_rgb_is_accepted(depth: int, colour: int) -> None:
    with pytest.raises(PngError, match="only 8-bit RGB"):
        png_header(png_of(1, 1, b"\0abc", depth=depth, colour=colour))


# -- the pixels ---------------------------------------------------------------------------------
@settings(max_examples=50, deadline=None)
@given(st.text(min_size=1, max_size=3000))
def test_encode_then_decode_returns_the_text(text: str) -> None:
    assert png_text(png_encode(text), BUDGET).rstrip("\n") == text.rstrip("\n")


@settings(max_examples=300)
@given(st.binary(max_size=400))
def test_png_text_of_any_bytes_returns_text_or_raises_its_errors(data: bytes) -> None:
    for png in (data, PNG_SIGNATURE + data, png_encode("{}")[:41] + data):
        with contextlib.suppress(PngError, BudgetExceeded):
            assert isinstance(png_text(png, BUDGET), str)


def test_width_one_decodes_like_any_width() -> None:
    text = b'{"op":"status"}' + b"\n" * 30
    rows = len(text) // 3
    raw = b"".join(b"\0" + text[3 * r : 3 * r + 3] for r in range(rows))
    assert png_text(png_of(1, rows, raw), BUDGET) == text.decode()


def test_a_zlib_bomb_behind_a_small_header_stops_at_the_header_size() -> None:
    png = png_of(10, 10, b"\0" * (64 << 20))  # 64 MB of pixels; the header says 310 bytes
    with pytest.raises(PngError, match="exceeds the 310 bytes its header announces"):
        png_text(png, BUDGET)


def test_short_pixel_data_is_refused() -> None:
    with pytest.raises(PngError, match="its header announces 310"):
        png_text(png_of(10, 10, b"\0" * 300), BUDGET)


def test_a_row_filter_other_than_none_is_refused() -> None:
    raw = b"\0abc" + b"\x01abc" + b"\0abc"
    with pytest.raises(PngError, match="row 1 uses filter type 1"):
        png_text(png_of(1, 3, raw), BUDGET)


def test_too_many_chunks_are_refused() -> None:
    head = png_encode("{}")[:33]
    body = b"".join(chunk(b"tEXt", b"x") for _ in range(BUDGET.max_png_chunks + 1))
    with pytest.raises(PngError, match="more than 4096 chunks"):
        png_text(head + body, BUDGET)


def test_the_work_clock_stops_a_decoding_that_goes_over_its_time() -> None:
    ticks = itertools.count()
    clock = lambda: float(next(ticks))  # noqa: E731 - a second of work per reading
    png = png_encode("x" * 5000)
    with pytest.raises(BudgetExceeded, match="over the budget of 50 ms of work"):
        png_text(png, BUDGET, clock=clock)


# -- values ---------------------------------------------------------------------------------------
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(), inner, max_size=6),
    max_leaves=60,
)


def exact_count(obj: Any) -> int:
    if isinstance(obj, dict):
        return 1 + sum(1 + exact_count(v) for v in obj.values())
    if isinstance(obj, list):
        return 1 + sum(exact_count(v) for v in obj)
    return 1


@given(JSON_VALUES)
def test_count_values_counts_every_value_and_key(obj: Any) -> None:
    n = exact_count(obj)
    assert count_values(obj, n) == n
    if n > 1:
        assert count_values(obj, n - 1) > n - 1  # stops once over the limit


@settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(JSON_VALUES)
def test_the_text_bound_is_never_below_the_count(obj: Any) -> None:
    assert json_values_bound(json.dumps(obj)) >= exact_count(obj)


def test_count_values_stops_early_on_a_huge_array() -> None:
    assert count_values([0] * 1_000_000, 10) > 10


# -- peeking at ids -----------------------------------------------------------------------------
@given(st.text(max_size=100))
def test_peek_id_reads_the_id_of_a_json_or_cbor_frame(id: str) -> None:
    frame = {"op": "publish", "id": id, "topic": "/a", "msg": {"data": "x" * 5000}}
    assert peek_id(json.dumps(frame)) == id
    assert peek_id(cbor2.dumps(frame)) == id


@given(st.one_of(st.text(max_size=300), st.binary(max_size=300)))
def test_peek_id_of_anything_is_a_string_or_none(payload: str | bytes) -> None:
    assert peek_id(payload) is None or isinstance(peek_id(payload), str)


# -- the protocol's triage ---------------------------------------------------------------------
def test_small_frames_are_decoded_at_once_large_ones_are_requests() -> None:
    p = BridgeProtocol()
    assert p.feed('{"op":"subscribe","topic":"/x"}', 0.0) == [ops.Subscribe(topic="/x")]
    big = json.dumps({"op": "publish", "id": "b", "topic": "/a", "msg": {"d": "x" * 70_000}})
    [request] = p.feed(big, 0.0)
    assert isinstance(request, DecodeRequest)
    assert (request.kind, request.id, request.allow_png) == ("frame", "b", True)
    [cbor] = p.feed(cbor2.dumps({"op": "subscribe", "topic": "/x", "pad": b"x" * 20_000}), 0.0)
    assert isinstance(cbor, DecodeRequest) and cbor.kind == "frame"


def test_every_png_is_a_request_and_its_header_is_judged_first() -> None:
    p = BridgeProtocol()
    small = base64.b64encode(png_encode('{"op":"subscribe","topic":"/x"}')).decode()
    [request] = p.feed(json.dumps({"op": "png", "id": "s", "data": small}), 0.0)
    assert isinstance(request, DecodeRequest) and request.kind == "png"
    assert run_decode(request, BUDGET, 1 << 24) == {"op": "subscribe", "topic": "/x"}
    # over the budget: refused at once, nothing for a worker
    raw = b"\0\n\n\n" * ((16 << 20) // 4)
    wide = base64.b64encode(png_of(1, len(raw) // 4, raw)).decode()
    assert p.feed(json.dumps({"op": "png", "id": "w", "data": wide}), 0.0) == []
    [s] = statuses(p)
    assert s["id"] == "w" and "over the decoding budget" in s["msg"]


def test_a_role_that_may_not_send_png_is_refused_before_the_data_is_read() -> None:
    p = BridgeProtocol()
    p.png_refusal = "observer may not send png-compressed frames; refused before decoding"
    assert p.feed('{"op":"png","id":"o","data":"!!"}', 0.0) == []
    [s] = statuses(p)
    assert s["id"] == "o" and s["msg"].startswith("observer may not send png")
    # inside fragments too
    inner = json.dumps({"op": "png", "id": "o2", "data": "!!"})
    half = len(inner) // 2
    for num, part in enumerate((inner[:half], inner[half:])):
        frag = {"op": "fragment", "id": "f", "data": part, "num": num, "total": 2}
        assert p.feed(json.dumps(frag), 0.0) == []
    assert statuses(p)[0]["msg"].startswith("observer may not send png")


def test_a_large_fragmented_message_is_decoded_by_a_worker() -> None:
    p = BridgeProtocol()
    text = json.dumps({"op": "subscribe", "id": "s", "topic": "/x", "pad": "y" * 100_000})
    pieces = [text[i : i + 30_000] for i in range(0, len(text), 30_000)]
    out: list[Any] = []
    for num, part in enumerate(pieces):
        frag = {"op": "fragment", "id": "f", "data": part, "num": num, "total": len(pieces)}
        out += p.feed(json.dumps(frag), 0.0)
    [request] = out
    assert isinstance(request, DecodeRequest) and request.kind == "text"
    [op] = p.receive_decoded(run_decode(request, BUDGET, 1 << 24), 0.0, request)
    assert isinstance(op, ops.Subscribe) and op.id == "s"


def test_a_png_text_of_too_many_values_is_refused_before_parsing() -> None:
    text = json.dumps({"op": "publish", "topic": "/a", "msg": {"data": [0] * 70_000}})
    data = base64.b64encode(png_encode(text)).decode()
    with pytest.raises(
        BudgetExceeded, match=r"may hold \d+ values, over the decoding budget of 65536"
    ):
        run_decode(DecodeRequest("png", data, "p"), BUDGET, 1 << 24)


def test_a_decoded_frame_of_too_many_values_is_refused() -> None:
    text = json.dumps({"op": "publish", "id": "n", "topic": "/a", "msg": {"d": [0] * 70_000}})
    with pytest.raises(BudgetExceeded) as info:
        run_decode(DecodeRequest("frame", text), BUDGET, 1 << 24)
    assert info.value.id == "n"


# -- the pool ----------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", ["process", "thread"])
async def test_the_pool_decodes_frames_and_pngs(backend: Any) -> None:
    decoder = InboundDecoder(BUDGET, 1 << 24, workers=1, backend=backend)
    try:
        big = {"op": "publish", "id": "a", "topic": "/a", "msg": {"data": "x" * 200_000}}
        assert await decoder.decode(DecodeRequest("frame", json.dumps(big), "a")) == big
        bad = await decoder.decode(DecodeRequest("frame", "{" * 100_000, "c"))
        assert isinstance(bad, FrameError) and "invalid JSON" in bad.msg
        png = base64.b64encode(png_encode(json.dumps({"op": "status"}))).decode()
        assert await decoder.decode(DecodeRequest("png", png, "p")) == {"op": "status"}
        many = json.dumps({"op": "publish", "id": "m", "msg": {"d": [0] * 70_000}})
        refused = await decoder.decode(DecodeRequest("frame", many, None))
        assert isinstance(refused, BudgetExceeded) and refused.id == "m"
        assert decoder.stats.png_inflated == 1 and decoder.stats.completed == 4
        assert decoder.pending == 0
    finally:
        decoder.close()


async def test_the_pool_refuses_a_frame_while_it_is_full() -> None:
    gate = threading.Event()

    def held(request: DecodeRequest, budget: DecodeBudget, max_bytes: int, portable: bool) -> Any:
        gate.wait(30)  # a worker busy until the test lets it go
        return work(request, budget, max_bytes, portable)

    decoder = InboundDecoder(BUDGET, 1 << 24, max_pending=2, backend="thread", work_fn=held)
    try:
        frame = json.dumps({"op": "status"})
        first = asyncio.ensure_future(decoder.decode(DecodeRequest("frame", frame, "a")))
        second = asyncio.ensure_future(decoder.decode(DecodeRequest("frame", frame, "b")))
        await asyncio.sleep(0)  # both submitted (and held)
        third = await decoder.decode(DecodeRequest("frame", frame, "c"))
        assert isinstance(third, DecoderBusy) and third.id == "c"
        assert "at most 2 at once" in third.msg
        gate.set()
        assert await first == await second == {"op": "status"}
        assert decoder.stats.refused_busy == 1
        assert await decoder.decode(DecodeRequest("frame", frame, "d")) == {"op": "status"}
    finally:
        gate.set()
        decoder.close()


def _decode_in_a_daemon(out: Any) -> None:
    async def go() -> tuple[str, Any]:
        decoder = InboundDecoder(BUDGET, 1 << 24)
        try:
            got = await decoder.decode(DecodeRequest("frame", json.dumps({"op": "status"})))
            return decoder.backend, got
        finally:
            decoder.close()

    out.put(asyncio.run(go()))


def test_a_daemonic_process_decodes_with_threads() -> None:
    # multiprocessing gives a daemonic process no children: the pool falls back to threads
    ctx = multiprocessing.get_context("spawn")
    out = ctx.Queue()
    proc = ctx.Process(target=_decode_in_a_daemon, args=(out,), daemon=True)
    proc.start()
    try:
        assert out.get(timeout=60) == ("thread", {"op": "status"})
    finally:
        proc.join(10)
