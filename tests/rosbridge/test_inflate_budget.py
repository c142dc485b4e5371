"""The transport's permessage-deflate budget (``server.http.ws_guard.InflateLimits``): sans-I/O
against websockets' own client protocol with a virtual clock, then over real sockets
(an address of its own)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from websockets.client import ClientProtocol
from websockets.exceptions import ConnectionClosed
from websockets.extensions.permessage_deflate import (
    ClientPerMessageDeflateFactory,
    ServerPerMessageDeflateFactory,
)
from websockets.frames import Frame
from websockets.uri import parse_uri

from server.http.ws_guard import CappedServerProtocol, InflateLimits
from tests.support.loopback import fresh_address

from .server_fixture import RunningServer, running_server
from .wsclient import RawClient

MIB = 1 << 20


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def connected(limits: InflateLimits, clock: Clock) -> tuple[ClientProtocol, CappedServerProtocol]:
    """A client and a server protocol after a handshake that negotiated permessage-deflate,
    the server authenticated (its pre-auth cap lifted)."""
    client = ClientProtocol(parse_uri("ws://h/"), extensions=[ClientPerMessageDeflateFactory()])
    server = CappedServerProtocol(
        4096,
        max_size=64 * MIB,
        extensions=[ServerPerMessageDeflateFactory()],
        inflate=limits,
        clock=clock,
    )
    request = client.connect()
    client.send_request(request)
    server.receive_data(b"".join(client.data_to_send()))
    [received] = server.events_received()
    server.send_response(server.accept(received))  # type: ignore[arg-type]
    client.receive_data(b"".join(server.data_to_send()))
    client.events_received()
    assert client.extensions and server.extensions  # negotiated
    server.lift()
    return client, server


def messages(server: CappedServerProtocol) -> list[Frame]:
    return [e for e in server.events_received() if isinstance(e, Frame)]


def test_one_turn_inflates_at_most_its_share_and_the_rest_waits_for_the_next() -> None:
    clock = Clock()
    limits = InflateLimits(per_turn_bytes=MIB, rate_bytes_per_s=1e12, burst_bytes=1e12)
    client, server = connected(limits, clock)
    for _ in range(100):
        client.send_text(b"x" * 60_000)  # 100 messages of 60 KB: ~8 KB compressed in all
    server.receive_data(b"".join(client.data_to_send()))
    got = messages(server)
    assert len(got) == 18  # 18 × 60 KB reaches 1 MiB; the parser stops at the next frame
    assert server.paced
    total = len(got)
    while total < 100:
        assert server.next_turn() == 0.0
        server.step()
        batch = messages(server)
        assert 0 < len(batch) <= 18
        total += len(batch)
    assert total == 100


def test_the_bucket_holds_the_parser_until_it_refills() -> None:
    clock = Clock()
    limits = InflateLimits(per_turn_bytes=64 * MIB, rate_bytes_per_s=MIB, burst_bytes=MIB)
    client, server = connected(limits, clock)
    for _ in range(40):
        client.send_text(b"x" * 60_000)
    server.receive_data(b"".join(client.data_to_send()))
    assert len(messages(server)) == 18  # the burst (1 MiB), and one frame into debt
    wait = server.next_turn()
    assert wait == pytest.approx((18 * 60_000 - MIB) / MIB)
    server.step()
    assert messages(server) == []  # nothing until the clock says so
    clock.now += wait
    assert server.next_turn() == 0.0
    server.step()
    assert len(messages(server)) == 1  # 60 KB more puts it in debt again


def test_uncompressed_frames_cost_nothing_of_the_budget() -> None:
    limits = InflateLimits(per_turn_bytes=MIB, rate_bytes_per_s=1.0, burst_bytes=1.0)
    client = ClientProtocol(parse_uri("ws://h/"))  # no permessage-deflate offered
    server = CappedServerProtocol(
        4096, max_size=64 * MIB, extensions=[ServerPerMessageDeflateFactory()], inflate=limits
    )
    client.send_request(client.connect())
    server.receive_data(b"".join(client.data_to_send()))
    [received] = server.events_received()
    server.send_response(server.accept(received))  # type: ignore[arg-type]
    client.receive_data(b"".join(server.data_to_send()))
    server.lift()
    for _ in range(40):
        client.send_text(b"x" * 60_000)
    server.receive_data(b"".join(client.data_to_send()))
    assert len(messages(server)) == 40 and not server.paced


def test_a_compressed_message_over_its_cap_fails_the_connection_saying_why() -> None:
    client, server = connected(InflateLimits(max_message_bytes=MIB), Clock())
    client.send_text(b"x" * (MIB + 1))
    server.receive_data(b"".join(client.data_to_send()))
    assert server.parser_exc is not None
    assert server.close_sent is not None and server.close_sent.code == 1009
    assert "compressed message inflates to over 1048576 bytes" in server.close_sent.reason
    # and at the cap it is taken
    client, server = connected(InflateLimits(max_message_bytes=MIB), Clock())
    client.send_text(b"x" * MIB)
    server.receive_data(b"".join(client.data_to_send()))
    assert [len(f.data) for f in messages(server)] == [MIB]


def test_lift_never_raises_the_transport_limit() -> None:
    _, server = connected(InflateLimits(), Clock())
    server.lift(128 * MIB)
    assert server.max_message_size == 64 * MIB
    server.lift(65536)
    assert server.max_message_size == 65536


# -- over sockets -----------------------------------------------------------------------------
@pytest.fixture
def srv(tmp_path: Path) -> Iterator[RunningServer]:
    with running_server(tmp_path, host=fresh_address()) as s:
        yield s


async def test_a_pilot_compressed_message_over_16_mib_is_closed_with_the_reason(
    srv: RunningServer,
) -> None:
    async with await RawClient.open(srv.url("pilot"), compression="deflate") as c:
        await c.send({"op": "publish", "topic": "/big", "msg": {"data": "x" * (17 * MIB)}})
        with pytest.raises(ConnectionClosed) as info:
            await c.expect(lambda m: False, timeout=10)
    assert info.value.rcvd is not None and info.value.rcvd.code == 1009
    assert "send it uncompressed" in info.value.rcvd.reason
    # one within it is inflated and answered by the endpoint
    async with await RawClient.open(srv.url("pilot"), compression="deflate") as c:
        msg = {"op": "publish", "id": "u", "topic": "/big", "msg": {"data": "x" * (5 * MIB)}}
        await c.send(json.dumps(msg))
        assert "unknown topic" in (await c.status("u", timeout=30))["msg"]


async def test_an_observer_flood_of_compressed_fragments_is_answered(srv: RunningServer) -> None:
    # ~8 KB on the wire, 6 MB inflated: parsed a turn at a time, each message answered
    async with await RawClient.open(srv.url("observer"), compression="deflate") as c:
        for n in range(100):
            await c.send(
                {
                    "op": "call_service",
                    "id": f"c{n}",
                    "service": "/rosapi/topics",
                    "pad": "x" * 60_000,
                }
            )
        answered: set[str] = set()
        while len(answered) < 100:  # a response, or a refusal (8 calls at a time), any order
            msg = await c.recv(timeout=30)
            answered.add(msg["id"])
    assert answered == {f"c{n}" for n in range(100)}
