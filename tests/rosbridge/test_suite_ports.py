"""rosbridge_suite's own WebSocket tests (rosbridge_server/test/websocket/*.test.py), ported.

The ROS node of the originals is the graph (internal publishers, subscribers and services);
the WebSocket clients are bare ``websockets`` clients sending exactly the originals' frames.
Sizes are scaled down where noted to keep this directory fast on a small CI machine.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

from tests.support.polling import until_async

from .server_fixture import RunningServer
from .wsclient import RawClient


async def test_smoke(srv: RunningServer) -> None:
    """smoke.test.py: 10 publishes each way between a WebSocket client and the node."""
    n, a_topic, b_topic = 10, "/a_topic", "/b_topic"
    ros_received: list[dict[str, Any]] = []
    srv.call(lambda: srv.graph.subscribe(a_topic, ros_received.append, type="std_msgs/String"))
    srv.call(srv.graph.advertise, b_topic, "std_msgs/String")
    async with await RawClient.open(srv.url()) as ws:
        await ws.send(
            {"op": "subscribe", "topic": b_topic, "type": "std_msgs/String", "queue_length": 0}
        )
        await ws.send({"op": "advertise", "topic": a_topic, "type": "std_msgs/String"})
        await until_async(
            lambda: srv.graph.subscribers(b_topic) and srv.graph.publishers(a_topic),
            5.0,
            "srv.graph.subscribers(b_topic) and srv.graph.publishers(a_topic)",
        )
        for _ in range(n):
            await ws.send({"op": "publish", "topic": a_topic, "msg": {"data": "A" * 10}})
        for _ in range(n):
            srv.graph.publish(b_topic, {"data": "B" * 10})
        got = [await ws.expect_op("publish") for _ in range(n)]
        await until_async(lambda: len(ros_received) == n, 5.0, "len(ros_received) == n")
    assert all(m == {"op": "publish", "topic": b_topic, "msg": {"data": "B" * 10}} for m in got)
    assert ros_received == [{"data": "A" * 10}] * n


async def test_call_service(srv: RuningServer if False else RunningServer) -> None:  # noqa: F821
    """call_service.test.py: a client calls a node's service and gets its response."""

    async def trigger(args: dict[str, Any]) -> dict[str, Any]:
        return {"success": True, "message": "called"}

    srv.call(srv.graph.advertise_service, "/test_service", "std_srvs/Trigger", trigger)
    async with await RawClient.open(srv.url()) as ws:
        await ws.send(
            {
                "op": "call_service",
                "id": "test-id",
                "service": "/test_service",
                "type": "std_srvs/Trigger",
                "args": {},
            }
        )
        r = await ws.expect_op("service_response")
    assert r == {
        "op": "service_response",
        "service": "/test_service",
        "result": True,
        "id": "test-id",
        "values": {"success": True, "message": "called"},
    }


async def test_advertise_service(srv: RunningServer) -> None:
    """advertise_service.test.py: a client provides a service; the node calls it."""
    async with await RawClient.open(srv.url()) as ws:
        await ws.send(
            {"op": "advertise_service", "type": "std_srvs/SetBool", "service": "/test_service"}
        )
        await until_async(
            lambda: srv.graph.service_type("/test_service") == "std_srvs/SetBool",
            5.0,
            "srv.graph.service_type('/test_service') == 'std_srvs/SetBool'",
        )
        future = asyncio.run_coroutine_threadsafe(
            srv.graph.call_service("/test_service", {"data": True}, timeout=5), srv.loop
        )
        req = await ws.expect_op("call_service")
        assert req["service"] == "/test_service" and req["args"] == {"data": True}
        assert req["id"] == "service_request:/test_service:1"
        await ws.send(
            {
                "op": "service_response",
                "service": "/test_service",
                "id": req["id"],
                "values": {"success": True, "message": "Hello world"},
                "result": True,
            }
        )
        values = await asyncio.wrap_future(future)
    assert values == {"success": True, "message": "Hello world"}


async def test_advertise_service_failure_and_disconnect(srv: RunningServer) -> None:
    """A provider answering result false, and one that disconnects mid-call."""
    async with await RawClient.open(srv.url()) as ws, await RawClient.open(srv.url()) as caller:
        await ws.send({"op": "advertise_service", "type": "a/B", "service": "flaky"})
        await until_async(
            lambda: srv.graph.service_type("/flaky") is not None,
            5.0,
            "srv.graph.service_type('/flaky') is not None",
        )
        await caller.send({"op": "call_service", "id": "c1", "service": "/flaky", "args": []})
        req = await ws.expect_op("call_service")
        assert req["service"] == "flaky"  # as the provider spelled it
        await ws.send(
            {"op": "service_response", "id": req["id"], "result": False, "values": "out of order"}
        )
        r = await caller.expect_op("service_response", id="c1")
        assert r["result"] is False and "out of order" in r["values"]
        await caller.send({"op": "call_service", "id": "c2", "service": "/flaky"})
        await ws.expect_op("call_service")
        await ws.close()
        r = await caller.expect_op("service_response", id="c2")
        assert r["result"] is False and "disconnected" in r["values"]


async def test_multiple_subscribers(srv: RunningServer) -> None:
    """multiple_subscribers.test.py: two clients on one topic both get the message."""
    srv.call(srv.graph.advertise, "/a_topic", "std_msgs/String")
    async with await RawClient.open(srv.url()) as c1, await RawClient.open(srv.url()) as c2:
        for c in (c1, c2):
            await c.send({"op": "subscribe", "topic": "/a_topic", "type": "std_msgs/String"})
        await until_async(
            lambda: len(srv.graph.subscribers("/a_topic")) == 2,
            5.0,
            "len(srv.graph.subscribers('/a_topic')) == 2",
        )
        srv.graph.publish("/a_topic", {"data": "hello"})
        for c in (c1, c2):
            m = await c.expect_op("publish")
            assert m == {"op": "publish", "topic": "/a_topic", "msg": {"data": "hello"}}


async def test_one_client_several_subscriptions_share_a_stream(srv: RunningServer) -> None:
    """Two subscription ids, one stream: one copy per message; unsubscribe by id."""
    srv.call(srv.graph.advertise, "/shared", "std_msgs/String")
    async with await RawClient.open(srv.url()) as c:
        await c.send({"op": "subscribe", "id": "s1", "topic": "/shared"})
        await c.send({"op": "subscribe", "id": "s2", "topic": "/shared", "throttle_rate": 0})
        await c.send({"op": "subscribe", "id": "s3", "topic": "shared"})  # another spelling
        await c.send({"op": "call_service", "id": "sync0", "service": "/rosapi/nodes"})
        await c.expect_op("service_response", id="sync0")  # the subscribes were handled
        srv.graph.publish("/shared", {"data": "1"})
        a = await c.expect_op("publish")
        b = await c.expect_op("publish")
        assert {a["topic"], b["topic"]} == {"/shared", "shared"}  # echoed as spelled
        await c.send({"op": "unsubscribe", "id": "s1", "topic": "/shared"})
        await c.send({"op": "unsubscribe", "id": "s3", "topic": "shared"})
        await c.send({"op": "call_service", "id": "sync", "service": "/rosapi/nodes"})
        await c.expect_op("service_response", id="sync")
        srv.graph.publish("/shared", {"data": "2"})
        m = await c.expect_op("publish")
        assert m["topic"] == "/shared" and m["msg"] == {"data": "2"}  # s2 still live
        await c.send({"op": "unsubscribe", "id": "s2", "topic": "/shared"})
        await c.send({"op": "call_service", "id": "sync2", "service": "/rosapi/nodes"})
        await c.expect_op("service_response", id="sync2")
        assert srv.graph.subscribers("/shared") == []


async def test_transient_local_publisher(srv: RunningServer) -> None:
    """transient_local_publisher.test.py: three later subscribers each get the last message."""
    srv.call(lambda: srv.graph.advertise("/a_topic", "std_msgs/String", latch=True))
    srv.graph.publish("/a_topic", {"data": "hello"})
    await until_async(
        lambda: srv.graph.latched("/a_topic") is not None,
        5.0,
        "srv.graph.latched('/a_topic') is not None",
    )
    for _ in range(3):
        async with await RawClient.open(srv.url()) as ws:
            await ws.send({"op": "subscribe", "topic": "/a_topic", "type": "std_msgs/String"})
            m = await ws.recv()
            assert m == {"op": "publish", "topic": "/a_topic", "msg": {"data": "hello"}}


async def test_rapid_disconnect_smoke(srv: RunningServer) -> None:
    """rapid_disconnect_smoke.test.py (3 rounds of 30 clients instead of 10 of 100)."""
    srv.call(srv.graph.advertise, "/a_topic", "std_msgs/String")
    payload = {"data": "A" * 10_000}
    stop = False

    async def publish_many() -> None:
        while not stop:
            for _ in range(20):
                srv.graph.publish("/a_topic", payload)
            await asyncio.sleep(0.005)  # the publishing rate: the test's input

    pub = asyncio.create_task(publish_many())
    try:
        for _ in range(3):
            clients = [await RawClient.open(srv.url()) for _ in range(30)]
            for c in clients:
                await c.send(
                    {
                        "op": "subscribe",
                        "topic": "/a_topic",
                        "type": "std_msgs/String",
                        "queue_length": 0,
                    }
                )
            for c in clients:
                c.ws.transport.abort()  # dropConnection(abort=True)
    finally:
        stop = True
        await pub
    # the server still serves, and every dropped client was cleaned up
    async with await RawClient.open(srv.url()) as ws:
        await ws.send({"op": "subscribe", "topic": "/a_topic"})
        await ws.send({"op": "call_service", "id": "sync", "service": "/rosapi/nodes"})
        await ws.expect_op("service_response", id="sync")
        srv.graph.publish("/a_topic", {"data": "alive"})
        await ws.expect(lambda m: m.get("msg") == {"data": "alive"})
        await until_async(
            lambda: len(srv.graph.subscribers("/a_topic")) == 1,
            5.0,
            "len(srv.graph.subscribers('/a_topic')) == 1",
        )


async def test_event_loop_starvation(srv: RunningServer) -> None:
    """event_loop_starvation.test.py: a probe gets its heartbeats while a load client is flooded.

    Scaled: 20 load topics of 8 kB messages at up to 200 Hz each, for the probe's 1.5 s window
    at 10 Hz.
    """
    n_topics = 20
    for i in range(n_topics):
        srv.call(srv.graph.advertise, f"/load_{i}", "geometry_msgs/PoseStamped")
    srv.call(srv.graph.advertise, "/probe", "std_msgs/String")
    blob = {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "x" * 8000}}
    stop = False

    async def load() -> None:
        while not stop:
            for i in range(n_topics):
                srv.graph.publish(f"/load_{i}", blob)
            await asyncio.sleep(0.005)  # the load's rate: the test's input

    sent: list[float] = []

    async def probe_beats() -> None:
        loop = asyncio.get_running_loop()
        while not stop:
            sent.append(loop.time())
            srv.graph.publish("/probe", {"data": str(len(sent))})
            await asyncio.sleep(0.1)  # the probe's 10 Hz: the test's input

    loader = asyncio.create_task(load())
    try:
        async with await RawClient.open(srv.url()) as load_client:
            for i in range(n_topics):
                await load_client.send({"op": "subscribe", "topic": f"/load_{i}"})
            drain = asyncio.create_task(_drain(load_client))
            await asyncio.sleep(0.5)  # the flood runs before the probe connects (deliberate)
            probe = await asyncio.wait_for(RawClient.open(srv.url()), 5)  # handshake not starved
            async with probe:
                await probe.send({"op": "subscribe", "topic": "/probe"})
                await until_async(
                    lambda: srv.graph.subscribers("/probe"), 5.0, "srv.graph.subscribers('/probe')"
                )
                beats = asyncio.create_task(probe_beats())
                got = 0
                loop = asyncio.get_running_loop()
                end = loop.time() + 1.5
                while loop.time() < end:
                    try:
                        m = await probe.recv(max(0.01, end - loop.time()))
                    except TimeoutError:
                        break
                    got += m.get("topic") == "/probe"
                stop = True
                await beats
            drain.cancel()
    finally:
        stop = True
        await loader
    # every heartbeat sent more than 0.2 s before the window closed must have arrived
    due = sum(1 for t in sent if t < end - 0.2)
    assert due >= 10 and got >= due, f"probe got {got} of {due} heartbeats"


async def _drain(client: RawClient) -> None:
    async for _ in client.ws:
        pass


async def test_list_args_and_rosapi_without_slash(srv: RunningServer) -> None:
    srv.call(srv.graph.advertise, "/uav/pose", "geometry_msgs/PoseStamped")
    async with await RawClient.open(srv.url()) as c:
        await c.send(
            {"op": "call_service", "id": "1", "service": "rosapi/topic_type", "args": ["/uav/pose"]}
        )
        r = await c.expect_op("service_response", id="1")
        assert r["values"] == {"type": "geometry_msgs/PoseStamped"}
        assert r["service"] == "rosapi/topic_type"
        await c.send(
            {
                "op": "call_service",
                "id": "2",
                "service": "/rosapi/message_details",
                "args": {"type": "std_msgs/msg/Header"},
            }
        )
        r = await c.expect_op("service_response", id="2")
        assert [t["type"] for t in r["values"]["typedefs"]] == [
            "std_msgs/Header",
            "builtin_interfaces/Time",
        ]
        await c.send({"op": "call_service", "id": "3", "service": "/rosapi/get_time"})
        t = (await c.expect_op("service_response", id="3"))["values"]["time"]
        assert t["sec"] == t["secs"] > 1_600_000_000


async def test_values_on_the_wire(srv: RunningServer) -> None:
    """uint8[] as base64 (list accepted), NaN as null, secs/nsecs accepted, stamp filled."""
    srv.call(srv.graph.advertise, "/img", "sensor_msgs/CompressedImage")
    got: list[dict[str, Any]] = []
    srv.call(lambda: srv.graph.subscribe("/img", got.append))
    async with await RawClient.open(srv.url()) as c:
        await c.send({"op": "subscribe", "topic": "/img"})
        await until_async(
            lambda: len(srv.graph.subscribers("/img")) == 2,
            5.0,
            "len(srv.graph.subscribers('/img')) == 2",
        )
        await c.send(
            {
                "op": "publish",
                "topic": "/img",
                "msg": {
                    "format": "jpeg",
                    "data": [1, 2, 255],
                    "header": {"stamp": {"secs": 5, "nsecs": 6}},
                },
            }
        )
        m = await c.expect_op("publish")
        assert m["msg"]["data"] == "AQL/" and m["msg"]["header"]["stamp"] == {
            "sec": 5,
            "nanosec": 6,
        }
        assert got[0]["data"] == b"\x01\x02\xff"
        await c.send({"op": "publish", "topic": "/img", "msg": {"format": "png"}})
        m = await c.expect_op("publish")
        assert m["msg"]["header"]["stamp"]["sec"] > 1_600_000_000 and m["msg"]["data"] == ""
        srv.call(srv.graph.advertise, "/f", "std_msgs/Float64")
        await c.send({"op": "subscribe", "topic": "/f"})
        await until_async(lambda: srv.graph.subscribers("/f"), 5.0, "srv.graph.subscribers('/f')")
        srv.graph.publish("/f", {"data": float("nan")})
        raw = await c.expect_op("publish", topic="/f")
        assert raw["msg"] == {"data": None}
    assert json.dumps(raw)  # valid JSON (no NaN token)
