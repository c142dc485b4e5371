"""Issue 14's findings at the WebSocket door, each reproduced over a real socket.

| finding                                         | answer now                               |
|-------------------------------------------------|------------------------------------------|
| a ``png`` frame before auth (200 000 IDAT chunks) | refused at its header, close 1009        |
| a small ``png``/``fragment`` op before auth     | status "not authenticated", close 1008   |
| a 1 MB frame before auth                        | refused at its header, close 1009        |
| a 900 000-chunk PNG after auth                  | status "more than 4096 chunks"; served   |
| ``auth`` with a lone surrogate                  | status "auth: invalid token", close 1008 |
| ``queue_length`` ≥ 2^63, huge ``throttle_rate`` | status "must be at most …"               |
| ``fragment_size: 1``                            | status "must be at least 1024"           |
| ``timeout: NaN`` on a call                      | status "finite number of seconds"        |
| 9 concurrent calls to a service never answering | the 9th fails "at most 8 at a time"      |
| a pilot publishes ``/console/reply``            | refused (``/fleet/*`` too)               |
| an observer asks who holds the lease            | "another pilot", no key                  |
| Origin ``…:8123.evil.example``, Host ``evil…``  | refused at the handshake                 |
| connections over the per-IP cap                 | closed 1013 with the reason              |
"""

from __future__ import annotations

import base64
import json
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus

from server.rosbridge.encode import PNG_SIGNATURE, png_encode
from tests.support.loopback import fresh_address
from tests.support.polling import until_async

from .server_fixture import RunningServer, running_server
from .wsclient import RawClient

HOST = fresh_address()


@pytest.fixture
def srv14(tmp_path: Path) -> Iterator[RunningServer]:
    with running_server(tmp_path, host=HOST) as s:
        yield s


def png_of_many_chunks(text: str, chunks: int) -> bytes:
    """``text`` as rosbridge's PNG, its zlib stream cut into ``chunks`` IDAT chunks (the
    attack of issue 14 used ~900 000 one-byte chunks)."""
    png = png_encode(text)
    ihdr_end = len(PNG_SIGNATURE) + 12 + 13
    (length,) = struct.unpack(">I", png[ihdr_end : ihdr_end + 4])
    stream = png[ihdr_end + 8 : ihdr_end + 8 + length]
    stream = stream + b"\0" * max(0, chunks - len(stream))  # pad to enough bytes to split
    step = max(1, len(stream) // chunks)
    body = b"".join(
        struct.pack(">I", len(part))
        + b"IDAT"
        + part
        + struct.pack(">I", zlib.crc32(b"IDAT" + part) & 0xFFFFFFFF)
        for part in (stream[i : i + step] for i in range(0, len(stream), step))
    )
    return png[:ihdr_end] + body + png[-12:]


async def closed_with(c: RawClient, timeout: float = 10.0) -> int | None:
    with pytest.raises(ConnectionClosed) as info:
        await c.expect(lambda m: False, timeout=timeout)
    return info.value.rcvd.code if info.value.rcvd is not None else None


async def test_png_bomb_before_auth_is_refused_unread(srv14: RunningServer) -> None:
    png = png_of_many_chunks('{"op":"auth","token":"x"}', 200_000)
    frame = json.dumps({"op": "png", "data": base64.b64encode(png).decode()})
    async with await RawClient.open(srv14.url(None)) as c:
        await c.send(frame)
        # the transport refuses it at the frame header (server.http.ws_guard; more in
        # test_preauth_cap.py); the app never sees it
        assert await closed_with(c) == 1009


async def test_small_png_or_fragment_before_auth_is_refused(srv14: RunningServer) -> None:
    inner = json.dumps({"op": "auth", "token": srv14.pilot})
    small = {"op": "png", "id": "p", "data": base64.b64encode(png_encode(inner)).decode()}
    async with await RawClient.open(srv14.url(None)) as c:
        await c.send(small)
        s = await c.status("p")
        assert s["msg"].startswith("not authenticated: 'png' refused")
        assert await closed_with(c) == 1008
    async with await RawClient.open(srv14.url(None)) as c:
        await c.send({"op": "fragment", "id": "f", "data": "{", "num": 0, "total": 2})
        assert (await c.status("f"))["msg"].startswith("not authenticated: 'fragment'")
        assert await closed_with(c) == 1008


async def test_large_frame_before_auth_closes(srv14: RunningServer) -> None:
    async with await RawClient.open(srv14.url(None)) as c:
        await c.send(json.dumps({"op": "auth", "token": "x" * (1 << 20)}))
        assert await closed_with(c) == 1009


async def test_png_bomb_after_auth_gets_an_error_and_the_connection_lives(
    srv14: RunningServer,
) -> None:
    png = png_of_many_chunks('{"op":"subscribe","topic":"/a","type":"std_msgs/String"}', 900_000)
    frame = json.dumps({"op": "png", "id": "bomb", "data": base64.b64encode(png).decode()})
    assert len(frame) < 16 << 20  # under the frame limit: the PNG decoder must refuse it
    async with await RawClient.open(srv14.url()) as c:
        await c.send(frame)
        s = await c.status(timeout=30)
        assert "PNG has more than 4096 chunks" in s["msg"]
        await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
        assert (await c.expect_op("service_response", id="t"))["result"] is True
        # a well-formed PNG of a few chunks still works
        ok = png_of_many_chunks(
            json.dumps({"op": "call_service", "id": "t2", "service": "/rosapi/topics"}), 5
        )
        await c.send({"op": "png", "data": base64.b64encode(ok).decode()})
        assert (await c.expect_op("service_response", id="t2"))["result"] is True


async def test_auth_with_a_lone_surrogate_is_answered(srv14: RunningServer) -> None:
    async with await RawClient.open(srv14.url(None)) as c:
        await c.send('{"op": "auth", "id": "a", "token": "\\ud800"}')
        assert (await c.status("a"))["msg"] == "auth: invalid token"
        assert await closed_with(c) == 1008


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("queue_length", 2**63, "'queue_length' must be at most 1000"),
        ("queue_length", 1e300, "'queue_length' must be at most 1000"),
        ("throttle_rate", 10**12, "'throttle_rate' must be at most 3600000"),
        ("fragment_size", 1, "'fragment_size' must be at least 1024"),
    ],
)
async def test_subscription_bounds(
    srv14: RunningServer, field: str, value: float, message: str
) -> None:
    async with await RawClient.open(srv14.url()) as c:
        await c.send(
            {
                "op": "subscribe",
                "id": "s",
                "topic": "/camera",
                "type": "std_msgs/String",
                field: value,
            }
        )
        assert message in (await c.status("s"))["msg"]


async def test_non_finite_call_timeout(srv14: RunningServer) -> None:
    async with await RawClient.open(srv14.url()) as c:
        await c.send('{"op":"call_service","id":"c","service":"/rosapi/topics","timeout":NaN}')
        assert "finite number of seconds" in (await c.status("c"))["msg"]


async def test_concurrent_calls_are_capped_per_connection(srv14: RunningServer) -> None:
    async with (
        await RawClient.open(srv14.url()) as provider,
        await RawClient.open(srv14.url()) as caller,
    ):
        await provider.send(
            {"op": "advertise_service", "service": "/slow", "type": "std_srvs/Trigger"}
        )
        await until_async(
            lambda: srv14.graph.service_type("/slow") is not None, 10.0, "/slow advertised"
        )
        for i in range(9):
            await caller.send({"op": "call_service", "id": f"c{i}", "service": "/slow"})
        refused = await caller.expect_op("service_response", id="c8")
        assert refused["result"] is False and "at most 8 at a time" in refused["values"]
        # the provider got the first eight; answering one frees a slot
        first = await provider.expect_op("call_service")
        await provider.send(
            {"op": "service_response", "id": first["id"], "values": {}, "result": True}
        )
        assert (await caller.expect_op("service_response", id="c0"))["result"] is True
        await caller.send({"op": "call_service", "id": "again", "service": "/slow"})
        assert (await provider.expect_op("call_service", service="/slow"))["args"] == {}


async def test_only_the_server_publishes_console_and_fleet(srv14: RunningServer) -> None:
    async with await RawClient.open(srv14.url()) as c:
        for topic, type_ in (
            ("/console/reply", "uav_console/Reply"),
            ("/uav2/console/reply", "uav_console/Reply"),
            ("/fleet/status", "uav_console/FleetStatus"),
        ):
            await c.send({"op": "advertise", "id": topic, "topic": topic, "type": type_})
            assert (await c.status(topic))["msg"] == f"pilot may not advertise {topic}"
            await c.send({"op": "publish", "id": "p" + topic, "topic": topic, "msg": {}})
            assert (await c.status("p" + topic))["msg"] == f"pilot may not publish to {topic}"
        # nor a drone's LTM's: its status would put a drone in the CTM's plans, its plan
        # service would take the drone's plans
        ltm = "/uav2/fleet/ltm_status"
        await c.send({"op": "advertise", "id": "ltm", "topic": ltm, "type": "std_msgs/String"})
        assert (await c.status("ltm"))["msg"] == f"pilot may not advertise {ltm}"
        await c.send({"op": "publish", "id": "pltm", "topic": ltm, "msg": {"data": "{}"}})
        assert (await c.status("pltm"))["msg"] == f"pilot may not publish to {ltm}"
        plan = "/uav2/fleet/flight_plan"
        await c.send(
            {"op": "advertise_service", "id": "plan", "service": plan, "type": "x/FlightPlan"}
        )
        assert "may not" in (await c.status("plan"))["msg"]
        await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
        topics = (await c.expect_op("service_response", id="t"))["values"]["topics"]
        assert ltm not in topics


async def test_lease_holder_is_secret(srv14: RunningServer) -> None:
    lease = {"op": "call_service", "service": "/console/lease"}
    async with (
        await RawClient.open(srv14.url()) as pilot,
        await RawClient.open(srv14.url("observer")) as observer,
    ):
        await pilot.send({**lease, "id": "a", "args": {"action": "acquire"}})
        mine = (await pilot.expect_op("service_response", id="a"))["values"]
        assert mine["held_by_me"] and mine["key"] and mine["holder"] == mine["key"]
        assert srv14.ctx.security.lease.key_matches(mine["key"])
        await observer.send({**lease, "id": "s", "args": {"action": "status"}})
        seen = (await observer.expect_op("service_response", id="s"))["values"]
        assert seen["holder"] == "another pilot" and seen["key"] == ""
        assert mine["key"] not in json.dumps(observer.seen)


async def test_host_and_origin_tricks_are_refused(srv14: RunningServer) -> None:
    with pytest.raises(InvalidStatus) as info:
        await RawClient.open(
            srv14.url(), additional_headers={"Origin": f"http://{HOST}:{srv14.port}.evil.example"}
        )
    assert info.value.response.status_code == 403
    # DNS rebinding: the attacker's name resolves to us, the browser sends its Origin and Host
    evil = f"http://evil.example:{srv14.port}"
    with pytest.raises(InvalidStatus):
        await RawClient.open(
            srv14.url(),
            additional_headers={"Origin": evil, "Host": f"evil.example:{srv14.port}"},
        )


async def test_connections_per_ip_are_capped(tmp_path: Path) -> None:
    with running_server(tmp_path, host=fresh_address(), max_connections_per_ip=3) as srv:
        clients = [await RawClient.open(srv.url(None)) for _ in range(3)]
        try:
            c = await RawClient.open(srv.url(None))
            assert await closed_with(c) == 1013
        finally:
            for c in clients:
                await c.close()
        # closed ones free their slots
        await until_async(lambda: not srv.ctx.connections, 10.0, "the closed slots freed")
        async with await RawClient.open(srv.url()) as again:
            await again.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
            assert (await again.expect_op("service_response", id="t"))["result"] is True


async def test_closed_connections_free_their_buffers(tmp_path: Path) -> None:
    """RSS grew 284 → 2361 MB over three rounds of four connections, freed only by a full GC
    (issue 14): now a closed connection drops its fragment buffers and unsent frames at once,
    whatever still refers to it."""
    import gc

    from server.rosbridge.protocol import BridgeProtocol

    with running_server(tmp_path, host=fresh_address()) as srv:
        for _ in range(3):
            clients = [await RawClient.open(srv.url()) for _ in range(4)]
            for c in clients:
                for n in range(4):  # 4 MB of a message that never completes
                    await c.send(
                        {
                            "op": "fragment",
                            "id": "big",
                            "data": "x" * (1 << 20),
                            "num": n,
                            "total": 9,
                        }
                    )
                await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
                await c.expect_op("service_response", id="t")
            for c in clients:
                await c.close()
            await until_async(lambda: not srv.ctx.connections, 10.0, "every connection closed")
        assert not srv.ctx.connections
        held = [
            o
            for o in gc.get_objects()
            if type(o) is BridgeProtocol and (o._fragments or o.frames_to_send())
        ]
        assert held == []


async def test_any_pilot_may_land_without_the_lease(srv14: RunningServer) -> None:
    seen: list[dict[str, object]] = []
    srv14.call(srv14.graph.advertise, "/ardrone/land", "std_msgs/Empty")
    srv14.call(srv14.graph.advertise, "/ardrone/takeoff", "std_msgs/Empty")
    srv14.call(srv14.graph.subscribe, "/ardrone/land", seen.append)
    async with (
        await RawClient.open(srv14.url()) as holder,
        await RawClient.open(srv14.url()) as other,
    ):
        await holder.send(
            {"op": "call_service", "id": "a", "service": "/console/lease", "args": {}}
        )
        assert (await holder.expect_op("service_response", id="a"))["values"]["held_by_me"]
        await other.send({"op": "publish", "id": "t", "topic": "/ardrone/takeoff", "msg": {}})
        assert "holds the pilot lease" in (await other.status("t"))["msg"]
        await other.send({"op": "publish", "id": "l", "topic": "/ardrone/land", "msg": {}})
        await other.send({"op": "call_service", "id": "q", "service": "/rosapi/topics"})
        await other.expect_op("service_response", id="q")
        assert not [m for m in other.seen if m.get("id") == "l"]  # no refusal
        assert seen == [{}]


async def test_drone_commands_over_rosbridge_are_audited(tmp_path: Path) -> None:
    from server.http.audit_trail import AuditTrail
    from server.store import AuditLog

    log = AuditLog(tmp_path / "audit.db")
    with running_server(tmp_path, host=fresh_address(), audit=AuditTrail(log)) as srv:
        rows_at_takeoff: list[list[str]] = []

        def on_takeoff(msg: object) -> None:  # what the log held when the command acted
            rows_at_takeoff.append([e.action for e in log.recent(10)])

        for topic in ("/ardrone/takeoff", "/ardrone/land"):
            srv.call(srv.graph.advertise, topic, "std_msgs/Empty")
        srv.call(srv.graph.advertise, "/cmd_vel", "geometry_msgs/Twist")
        srv.call(srv.graph.subscribe, "/ardrone/takeoff", on_takeoff)

        def actions() -> list[str]:
            return [e.action for e in reversed(log.recent(100))]

        async def wait_for(n: int) -> list[str]:
            """The audit's actions once it holds ``n`` (rows are written off the loop)."""
            await until_async(lambda: len(actions()) >= n, 10.0, f"{n} audit rows")
            return actions()

        async with await RawClient.open(srv.url()) as c:
            await c.send({"op": "publish", "topic": "/ardrone/takeoff", "msg": {}})
            assert await wait_for(2) == ["intent:takeoff", "outcome:takeoff"]
            assert rows_at_takeoff == [["intent:takeoff"]]  # intent committed before acting
            await c.send({"op": "publish", "topic": "/ardrone/land", "msg": {}})
            assert (await wait_for(4))[2:] == ["intent:land", "outcome:land"]
            jog = {"linear": {"x": 0.3, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0}}
            for _ in range(5):
                await c.send({"op": "publish", "topic": "/cmd_vel", "msg": jog})
            await c.send({"op": "publish", "topic": "/cmd_vel", "msg": {}})
            got = await wait_for(8)
            assert got[4:] == [
                "intent:jog_start",
                "outcome:jog_start",
                "intent:jog_stop",
                "outcome:jog_stop",
            ]
    log.close()
