"""Bad input over a real socket: each gets its documented answer, and others are still served.

| input                              | answer                                                   |
|------------------------------------|----------------------------------------------------------|
| invalid JSON                       | status error "invalid JSON: …"                           |
| JSON that is not an object         | status error "a frame must be a JSON object …"           |
| missing ``op``                     | status error "frame has no 'op' field", with the id      |
| unknown op                         | status error "unknown op 'x'", with the id               |
| wrong field type                   | status error naming op and field, with the id            |
| publish to an unknown topic        | status error "unknown topic; advertise it first …"       |
| advertise an unknown type          | status error "unknown message type …"                    |
| a msg that does not match its type | status error naming the field path                       |
| a 20 MiB frame (limit 16 MiB)      | status error "exceeds the limit"; a second: close 1009   |
| 10 000 frames at once              | status error "rate limit exceeded", then close 1008      |
| a client that never reads          | its oldest frames dropped; closed 1008 after a stall     |
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
from websockets.exceptions import ConnectionClosed

from tests.support.polling import until_async

from .server_fixture import RunningServer, running_server
from .wsclient import RawClient


async def test_malformed_frames_get_status_errors(srv: RunningServer) -> None:
    async with await RawClient.open(srv.url()) as c:
        await c.send("{not json")
        assert (await c.status())["msg"].startswith("invalid JSON")
        await c.send("[1, 2]")
        assert "must be a JSON object" in (await c.status())["msg"]
        await c.send({"id": "m1", "topic": "/x"})
        s = await c.status("m1")
        assert s["level"] == "error" and s["msg"] == "frame has no 'op' field"
        await c.send({"op": "fly_to_the_moon", "id": "u1"})
        assert (await c.status("u1"))["msg"] == "unknown op 'fly_to_the_moon'"
        await c.send({"op": "subscribe", "id": "w1", "topic": 5})
        assert (await c.status("w1"))["msg"] == "subscribe: field 'topic' must be a string"
        await c.send({"op": "subscribe", "id": "w2", "topic": "/a", "throttle_rate": "fast"})
        assert "throttle_rate" in (await c.status("w2"))["msg"]
        await c.send({"op": "subscribe", "id": "w3", "topic": "/a", "compression": "zip"})
        assert "compression 'zip'" in (await c.status("w3"))["msg"]
        await c.send({"op": "publish", "id": "p1", "topic": "/never/advertised", "msg": {}})
        assert "unknown topic" in (await c.status("p1"))["msg"]
        await c.send({"op": "advertise", "id": "a1", "topic": "/t", "type": "nope_msgs/Thing"})
        assert "unknown message type nope_msgs/Thing" in (await c.status("a1"))["msg"]
        await c.send({"op": "advertise", "id": "a2", "topic": "/t", "type": "not a type"})
        assert "is not a message type" in (await c.status("a2"))["msg"]
        await c.send({"op": "subscribe", "id": "s1", "topic": "/unknown/topic"})
        assert "unknown topic and no type" in (await c.status("s1"))["msg"]
        await c.send({"op": "advertise", "topic": "/twist", "type": "geometry_msgs/Twist"})
        await c.send(
            {"op": "publish", "id": "p2", "topic": "/twist", "msg": {"linear": {"x": "fast"}}}
        )
        assert (await c.status("p2"))[
            "msg"
        ] == "msg.linear.x must be a number (float64), not a string"
        await c.send({"op": "publish", "id": "p3", "topic": "/twist", "msg": {"linear": {"w": 1}}})
        assert "no field 'w'" in (await c.status("p3"))["msg"]
        await c.send({"op": "unsubscribe", "id": "nope", "topic": "/twist"})
        assert "not subscribed" in (await c.status("nope"))["msg"]
        await c.send({"op": "service_response", "id": "x", "values": {}})
        assert "no call 'x'" in (await c.status("x"))["msg"]
        await c.send(b"\xff\x00garbage")
        assert "CBOR" in (await c.status())["msg"]
        # and the connection still works
        await c.send({"op": "call_service", "id": "ok", "service": "/rosapi/topics"})
        r = await c.expect_op("service_response", id="ok")
        assert r["result"] is True and "/twist" in r["values"]["topics"]


async def test_failed_service_call_has_values_and_id(srv: RunningServer) -> None:
    async with await RawClient.open(srv.url()) as c:
        await c.send({"op": "call_service", "id": "c1", "service": "/missing"})
        r = await c.expect_op("service_response", id="c1")
        assert r["result"] is False and "does not exist" in r["values"]


async def test_oversized_frame_then_close_1009(srv: RunningServer) -> None:
    big = json.dumps({"op": "publish", "topic": "/big", "msg": {"data": "x" * (20 << 20)}})
    # compressed (permessage-deflate), the transport stops inflating it at the frame limit
    async with await RawClient.open(srv.url(), compression="deflate") as c:
        await c.send(big)
        with pytest.raises(ConnectionClosed) as info:
            await c.expect(lambda m: False, timeout=20)
        assert info.value.rcvd is not None and info.value.rcvd.code == 1009
        assert "send it uncompressed" in info.value.rcvd.reason
    async with (
        await RawClient.open(srv.url(), compression=None) as c,
        await RawClient.open(srv.url()) as other,
    ):
        await c.send(big)
        s = await c.status(timeout=20)
        assert "exceeds the limit of 16777216 bytes" in s["msg"]
        # the other client is served meanwhile
        await other.send({"op": "call_service", "id": "t", "service": "rosapi/topics"})
        assert (await other.expect_op("service_response", id="t"))["result"] is True
        await c.send(big)
        with pytest.raises(ConnectionClosed) as info:
            await c.expect(lambda m: False, timeout=20)
        assert info.value.rcvd is not None and info.value.rcvd.code == 1009


async def test_flood_of_10000_frames_is_limited_then_closed(tmp_path: Path) -> None:
    with running_server(tmp_path, rate_limit_per_s=1000.0, rate_burst=2000) as srv:
        await _flood(srv)


async def _flood(srv: RunningServer) -> None:
    srv.call(srv.graph.advertise, "/flood", "std_msgs/Int32")
    got: list[int] = []
    srv.call(lambda: srv.graph.subscribe("/flood", lambda m: got.append(m["data"])))
    async with await RawClient.open(srv.url()) as flood, await RawClient.open(srv.url()) as other:
        frames = [
            json.dumps({"op": "publish", "topic": "/flood", "msg": {"data": i}})
            for i in range(10_000)
        ]
        with pytest.raises(ConnectionClosed):
            for f in frames:
                await flood.send(f)
            await flood.expect(lambda m: False, timeout=20)
        statuses = [m for m in flood.seen if isinstance(m, dict) and m.get("op") == "status"]
        assert statuses and "rate limit exceeded" in statuses[0]["msg"]
        assert flood.ws.close_code == 1008
        # the first burst got through in order, the rest was refused
        assert 2000 <= len(got) < 8000 and got[:10] == list(range(10))
        await other.send({"op": "call_service", "id": "t", "service": "/rosapi/nodes"})
        assert (await other.expect_op("service_response", id="t"))["result"] is True


async def test_client_that_never_reads(tmp_path: Path) -> None:
    with running_server(tmp_path, stall_close_s=1.0, out_queue_frames=50) as srv:
        srv.call(srv.graph.advertise, "/firehose", "std_msgs/String")
        host, port = "127.0.0.1", srv.port
        reader, writer = await asyncio.open_connection(host, port)
        # a hand-made handshake, then subscribe, then never read again
        writer.write(
            (
                f"GET /rosbridge?token={srv.pilot} HTTP/1.1\r\nHost: {host}:{port}\r\n"
                "Upgrade: websocket\r\nConnection: Upgrade\r\n"
                "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
            ).encode()
        )
        await writer.drain()
        head = await reader.readuntil(b"\r\n\r\n")
        assert b" 101 " in head
        payload = json.dumps({"op": "subscribe", "topic": "/firehose"}).encode()
        mask = b"\x01\x02\x03\x04"
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        writer.write(bytes([0x81, 0x80 | len(payload)]) + mask + masked)
        await writer.drain()
        async with await RawClient.open(srv.url()) as other:
            await other.send({"op": "subscribe", "topic": "/firehose"})
            await until_async(
                lambda: len(srv.graph.subscribers("/firehose")) == 2, 10.0, "both subscribed"
            )
            blob = "y" * 100_000
            for i in range(200):  # 20 MB towards a client that reads nothing
                srv.graph.publish("/firehose", {"data": f"{i}:{blob}"})  # thread-safe
                if i % 50 == 0:  # the reading client's loop runs now and then
                    await asyncio.sleep(0.01)
            # the reading client still gets messages, up to the last one
            await other.expect(
                lambda m: (
                    isinstance(m, dict) and m.get("msg", {}).get("data", "").startswith("199:")
                ),
                timeout=20,
            )
            # the stalled connection is closed by the server (its subscription removed)
            await until_async(
                lambda: len(srv.graph.subscribers("/firehose")) == 1,
                15.0,
                "the stalled client's subscription removed",
            )
        # reset the stalled socket so the server's unflushed transport goes away before shutdown
        writer.transport.abort()
        await until_async(lambda: not srv.ctx.connections, 10.0, "both connections gone")
