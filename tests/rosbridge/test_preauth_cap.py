"""The transport's pre-auth frame cap (``server.http.ws_guard``, issue 14) over real sockets
(addresses of its own), with raw frames written under the ``websockets`` client:

| sent without a token                                  | answer                              |
|-------------------------------------------------------|-------------------------------------|
| a header announcing 16 MB, then a trickle of 1 KB     | close 1009 after the header, unread |
| a message of two 3 KB fragments                       | close 1009 at the second            |
| ``set_level`` (allowed before auth), then 16 MB       | close 1009: the cap outlives it     |
| ``auth`` and a 100 KB ``publish`` in one TCP write    | authenticated, the publish served   |

and with a token at the handshake a 100 KB ``publish`` is served. Under uvicorn's plain
implementation (no transport cap) the endpoint's own check still answers a large pre-auth frame.
"""

from __future__ import annotations

import asyncio
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.frames import Frame, Opcode

from tests.support.loopback import fresh_address
from tests.support.polling import until_async

from .server_fixture import RunningServer, running_server
from .wsclient import RawClient

HOST = fresh_address()
BIG = 100 * 1024


@pytest.fixture
def srv78(tmp_path: Path) -> Iterator[RunningServer]:
    with running_server(tmp_path, host=HOST) as s:
        yield s


def frame(data: bytes | str, *, opcode: Opcode = Opcode.TEXT, fin: bool = True) -> bytes:
    """One client frame (masked, as RFC 6455 §5.3 requires of clients)."""
    payload = data.encode() if isinstance(data, str) else data
    return Frame(opcode, payload, fin=fin).serialize(mask=True)


def header_announcing(length: int) -> bytes:
    """A masked text frame's header (FIN, 64-bit length, mask key) and no payload."""
    return bytes([0x81, 0x80 | 127]) + length.to_bytes(8, "big") + os.urandom(4)


def write(c: RawClient, data: bytes) -> None:
    """Bytes straight onto the socket, past the client's own framing."""
    c.ws.transport.write(data)


async def close_code(c: RawClient) -> tuple[int | None, str]:
    with pytest.raises(ConnectionClosed) as info:
        await c.expect(lambda m: False, timeout=10)
    rcvd = info.value.rcvd
    return (rcvd.code, rcvd.reason) if rcvd is not None else (None, "")


async def trickle_until_closed(c: RawClient, limit: int) -> tuple[int, int | None, str]:
    """Send 1 KB at a time until the server closes (or ``limit`` bytes went): (sent, code,
    reason). Each pause only paces the trickle; nothing is asserted on time."""
    recv = asyncio.ensure_future(c.ws.recv())
    sent = 0
    while not recv.done() and sent < limit:
        write(c, os.urandom(1024))
        sent += 1024
        await asyncio.wait({recv}, timeout=0.1)
    with pytest.raises(ConnectionClosed) as info:
        await asyncio.wait_for(recv, 10)
    rcvd = info.value.rcvd
    return sent, (rcvd.code if rcvd else None), (rcvd.reason if rcvd else "")


async def received(srv: RunningServer, topic: str, got: list[Any]) -> Any:
    await until_async(lambda: got, 10.0, f"a message published on {topic}")
    return got[0]


def publish_frames(topic: str, size: int) -> list[str]:
    return [
        json.dumps({"op": "advertise", "topic": topic, "type": "std_msgs/String"}),
        json.dumps({"op": "publish", "topic": topic, "msg": {"data": "x" * size}}),
    ]


async def test_a_16mb_frame_before_auth_is_refused_at_its_header(srv78: RunningServer) -> None:
    async with await RawClient.open(srv78.url(None)) as c:
        write(c, header_announcing(16 << 20))
        sent, code, reason = await trickle_until_closed(c, limit=64 * 1024)
    assert code == 1009
    assert "before authentication" in reason and "4096" in reason
    assert sent < 64 * 1024  # closed long before the 16 MB it announced


async def test_a_fragmented_message_before_auth_counts_as_one(srv78: RunningServer) -> None:
    async with await RawClient.open(srv78.url(None)) as c:
        write(c, frame("x" * 3000, fin=False))
        write(c, frame("y" * 3000, opcode=Opcode.CONT))
        assert (await close_code(c))[0] == 1009


async def test_the_cap_outlives_frames_that_do_not_authenticate(srv78: RunningServer) -> None:
    async with await RawClient.open(srv78.url(None)) as c:
        # set_level is allowed before auth; the 16 MB header pipelined behind it is judged
        # after the server handled it: still unauthenticated, so still capped
        level = frame(json.dumps({"op": "set_level", "level": "info"}))
        write(c, level + header_announcing(16 << 20))
        sent, code, _ = await trickle_until_closed(c, limit=64 * 1024)
    assert code == 1009 and sent < 64 * 1024


async def test_frames_pipelined_behind_auth_get_the_full_limit(srv78: RunningServer) -> None:
    got: list[Any] = []
    srv78.call(lambda: srv78.graph.subscribe("/big", got.append, type="std_msgs/String"))
    level = json.dumps({"op": "set_level", "level": "info"})
    auth = json.dumps({"op": "auth", "id": "a", "token": srv78.pilot})
    async with await RawClient.open(srv78.url(None)) as c:
        # one write: the server's first read holds auth and the 100 KB publish together
        write(c, b"".join(frame(f) for f in [level, auth, *publish_frames("/big", BIG)]))
        assert (await c.status("a"))["msg"] == "authenticated as pilot"
        msg = await received(srv78, "/big", got)
    assert len(msg["data"]) == BIG


async def test_a_token_at_the_handshake_lifts_the_cap_at_once(srv78: RunningServer) -> None:
    got: list[Any] = []
    srv78.call(lambda: srv78.graph.subscribe("/big", got.append, type="std_msgs/String"))
    async with await RawClient.open(srv78.url()) as c:
        for f in publish_frames("/big", BIG):
            await c.send(f)
        msg = await received(srv78, "/big", got)
    assert len(msg["data"]) == BIG


async def test_without_the_transport_cap_the_endpoint_still_refuses(tmp_path: Path) -> None:
    with running_server(tmp_path, host=fresh_address(), ws="websockets-sansio") as srv:
        async with await RawClient.open(srv.url(None)) as c:
            await c.send(json.dumps({"op": "auth", "token": "x" * 8192}))
            assert "before auth" in (await c.status())["msg"]
            assert (await close_code(c))[0] == 1008
