"""Inbound decoding budgets over real sockets (addresses of their own): the 1-pixel-wide PNG
that froze the server, sent by each role.

| sent                                                  | answer                                 |
|-------------------------------------------------------|----------------------------------------|
| the 21 KB ``png`` frame unpacking to 16 MB, observer  | status "observer may not send png…",   |
|                                                       | nothing inflated                       |
| the same, pilot (no lease needed to send it)          | status naming the budget, refused at   |
|                                                       | its header, nothing inflated           |
| the same, no token                                    | refused at its frame header (1009);    |
|                                                       | a 4 KB one: "not authenticated"       |
| a frame over 64 KB from an observer                   | refused at its frame header (1009);    |
|                                                       | plain transport: status with its id    |
| a fragmented message over 64 KB from an observer      | status error, nothing decoded          |
| a ``png`` within the budget, pilot                    | decoded off the loop, served           |
| the attack from all three roles at once, under        | ``/api/v1/health`` answers while it    |
| ``uav-console serve``                                 | runs                                   |
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import signal
import struct
import subprocess
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.exceptions import ConnectionClosed

from server.rosbridge.encode import PNG_SIGNATURE, png_encode
from tests.support.loopback import free_port, fresh_address
from tests.support.polling import until_async

from .server_fixture import RunningServer, running_server
from .wsclient import RawClient

HOST = fresh_address()
SERVE_HOST = fresh_address()
ROOT = Path(__file__).resolve().parents[2]
INNER = {"op": "call_service", "id": "inner", "service": "/rosapi/topics"}


def _chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def one_pixel_wide_png(op: dict[str, Any], raw_bytes: int = 16 << 20) -> bytes:
    """``op``'s JSON as a 1-pixel-wide RGB PNG padded with newlines to ``raw_bytes`` of pixel
    rows (4 bytes a row: the filter byte and one pixel): the frame of the finding, whose
    decoding cost grew with its row count."""
    rows = raw_bytes // 4
    text = json.dumps(op).encode()
    text += b"\n" * (3 * rows - len(text))
    raw = b"".join(b"\x00" + text[3 * r : 3 * r + 3] for r in range(rows))
    ihdr = struct.pack(">IIBBBBB", 1, rows, 8, 2, 0, 0, 0)
    return (
        PNG_SIGNATURE
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"IDAT", zlib.compress(raw, 9))
        + _chunk(b"IEND", b"")
    )


@pytest.fixture(scope="module")
def attack_png() -> bytes:
    return one_pixel_wide_png(INNER)


def png_op(png: bytes, id: str) -> str:
    return json.dumps({"op": "png", "id": id, "data": base64.b64encode(png).decode()})


@pytest.fixture
def srv(tmp_path: Path) -> Iterator[RunningServer]:
    with running_server(tmp_path, host=HOST) as s:
        yield s


def test_the_attack_frame_is_the_one_of_the_finding(attack_png: bytes) -> None:
    frame = png_op(attack_png, "x")
    assert 20_000 < len(frame) < 24_000  # the finding's frame: 21 857 bytes, 16 MB of pixels


async def test_observer_png_is_refused_before_anything_is_decoded(
    srv: RunningServer, attack_png: bytes
) -> None:
    async with await RawClient.open(srv.url("observer")) as c:
        await c.send(png_op(attack_png, "obs"))
        s = await c.status("obs", timeout=30)
        assert s["msg"].startswith("observer may not send png-compressed frames")
        # judged by role before the data is read: garbage data gets the same answer
        await c.send({"op": "png", "id": "junk", "data": "!!"})
        assert (await c.status("junk"))["msg"].startswith("observer may not send png")
        # the connection still serves what an observer may do
        await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
        assert (await c.expect_op("service_response", id="t"))["result"] is True
    assert srv.ctx.decoder.stats.png_inflated == 0
    assert srv.ctx.decoder.stats.submitted == 0


async def test_observer_frames_over_64_kb_are_refused_unread(srv: RunningServer) -> None:
    pad = "y" * 100_000
    async with await RawClient.open(srv.url("observer")) as c:
        # the transport refuses it at its frame header (the role's limit, ``ws_guard``)
        await c.send({"op": "subscribe", "id": "huge", "topic": "/x", "pad": pad})
        with pytest.raises(ConnectionClosed) as info:
            await c.expect(lambda m: False, timeout=10)
        assert info.value.rcvd is not None and info.value.rcvd.code == 1009
        assert "message over 65536 bytes" in info.value.rcvd.reason
    async with await RawClient.open(srv.url("observer")) as c:
        # nor may it be reassembled from fragments
        text = json.dumps({"op": "subscribe", "id": "frag", "topic": "/x", "pad": pad})
        for num, start in enumerate(range(0, len(text), 30_000)):
            part = text[start : start + 30_000]
            await c.send({"op": "fragment", "id": "f", "data": part, "num": num, "total": 4})
        s = await c.status("f")
        assert "fragmented message exceeds the limit of 65536 bytes" in s["msg"]
        await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
        assert (await c.expect_op("service_response", id="t"))["result"] is True
    assert srv.ctx.decoder.stats.submitted == 0


async def test_observer_frames_over_64_kb_under_a_plain_transport(tmp_path: Path) -> None:
    # without the transport's limit (uvicorn's own protocol) the endpoint answers it
    with running_server(tmp_path, host=HOST, ws="websockets-sansio") as srv:
        async with await RawClient.open(srv.url("observer")) as c:
            await c.send({"op": "subscribe", "id": "huge", "topic": "/x", "pad": "y" * 100_000})
            s = await c.status("huge")
            assert "an observer may send frames of at most 65536 bytes" in s["msg"]
            await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
            assert (await c.expect_op("service_response", id="t"))["result"] is True
        assert srv.ctx.decoder.stats.submitted == 0


async def test_pilot_png_over_the_budget_is_refused_at_its_header(
    srv: RunningServer, attack_png: bytes
) -> None:
    async with await RawClient.open(srv.url("pilot")) as c:
        await c.send(png_op(attack_png, "big"))
        s = await c.status("big", timeout=30)
        assert "1×4194304 pixels" in s["msg"] and "budget" in s["msg"], s["msg"]
        assert srv.ctx.decoder.stats.png_inflated == 0  # refused before inflating
        # a PNG within the budget is decoded (off the loop) and served
        ok = png_encode(json.dumps({**INNER, "id": "ok"}) + " " * (1 << 20))
        await c.send(png_op(ok, "fine"))
        assert (await c.expect_op("service_response", id="ok", timeout=30))["result"] is True
    assert srv.ctx.decoder.stats.png_inflated == 1


async def test_no_token_png_is_refused_at_its_frame_header(
    srv: RunningServer, attack_png: bytes
) -> None:
    async with await RawClient.open(srv.url(None)) as c:
        await c.send(png_op(attack_png, "anon"))
        with pytest.raises(ConnectionClosed) as info:
            await c.expect(lambda m: False, timeout=10)
        assert info.value.rcvd is not None and info.value.rcvd.code == 1009
    # one that fits in the 4 KB a connection may send before auth (and unpacks to 2 MB)
    small = png_op(one_pixel_wide_png(INNER, 2 << 20), "small")
    assert len(small) < 4096
    async with await RawClient.open(srv.url(None)) as c:
        await c.send(small)
        assert (await c.status("small"))["msg"].startswith("not authenticated: 'png' refused")
    assert srv.ctx.decoder.stats.png_inflated == 0
    assert srv.ctx.decoder.stats.submitted == 0


# -- the whole server under attack ----------------------------------------------------------
PILOT = "pilot-token-decode-budget"
OBSERVER = "observer-token-decode-budget"


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[str, int]]:
    """``uav-console serve --drone none`` in its own process: the real /health and rosbridge."""
    host = SERVE_HOST
    port = free_port(host)
    cmd = [sys.executable, "-m", "server", "serve", "--host", host, "--port", str(port)]
    cmd += ["--drone", "none", "--data-dir", str(tmp_path), "--token", PILOT]
    cmd += ["--observer-token", OBSERVER]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    try:
        for _ in range(600):  # up to 60 s to start under load
            if proc.poll() is not None:
                raise RuntimeError(f"serve exited: {proc.stderr.read() if proc.stderr else ''}")
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"http://{host}:{port}/api/v1/health", timeout=5).status_code == 200:
                    break
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=0.1)
        else:
            raise RuntimeError("serve did not answer /health")
        yield host, port
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()


async def test_health_answers_while_every_role_sends_the_attack(
    served: tuple[str, int], attack_png: bytes
) -> None:
    host, port = served
    frame = png_op(attack_png, "a")
    base = f"ws://{host}:{port}/rosbridge"
    events: list[str] = []
    stop = asyncio.Event()

    async def flood(c: RawClient) -> None:
        """Keep two attack frames in flight until told to stop; log each answer (a refusal,
        or what the frame's op got if it was decoded)."""
        await c.send(frame)
        while not stop.is_set():
            await c.send(frame)
            await c.recv(timeout=600)
            events.append("answered")

    async def anonymous() -> None:
        """Connect without a token and send the frame, again and again (whatever happens)."""
        while not stop.is_set():
            with contextlib.suppress(Exception):
                async with await RawClient.open(base) as c:
                    await c.send(frame)
                    with contextlib.suppress(ConnectionClosed):
                        await c.expect(lambda m: False, timeout=30)
            events.append("closed")

    clients = [await RawClient.open(f"{base}?token={t}") for t in (PILOT, OBSERVER)]
    floods = [asyncio.create_task(flood(c)) for c in clients]
    attackers = [*floods, asyncio.create_task(anonymous())]
    answers = 0
    try:
        async with httpx.AsyncClient(timeout=120) as h, asyncio.timeout(120):
            # 120 s bounds the test only; nothing is timed
            await until_async(lambda: "answered" in events, 120, "the attack under way")
            while answers < 5:
                r = await h.get(f"http://{host}:{port}/api/v1/health")
                assert r.status_code == 200
                answers += 1
                events.append("health")
                stopped = [t.exception() for t in floods if t.done()]
                assert not stopped, f"a flood stopped: {stopped!r}"
            # and the attack goes on after the last answer: /health was served during it
            seen = len(events)
            await until_async(
                lambda: "answered" in events[seen:], 120, "an answer after the last /health"
            )
    finally:
        stop.set()
        for t in attackers:
            t.cancel()
        await asyncio.gather(*attackers, return_exceptions=True)
        for c in clients:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(c.close(), 10)
    health = [i for i, e in enumerate(events) if e == "health"]
    assert answers == 5
    # attack frames answered before the first /health answer and after the last one
    assert events[: health[0]].count("answered") >= 1
    assert events[health[-1] :].count("answered") >= 1
