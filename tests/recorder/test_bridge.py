"""cbor-raw subscriptions, /rosout and rosapi's raw types over a real rosbridge WebSocket."""

from __future__ import annotations

import logging
from typing import Any

import cbor2

from server.graph import Graph
from server.nodes.rosout import ERROR, INFO, WARN, Rosout
from server.ros1 import codec_for, definition
from tests.rosbridge.server_fixture import RunningServer
from tests.rosbridge.wsclient import RawClient
from tests.support.polling import until_async


async def test_cbor_raw_is_ros1_bytes_in_a_cbor_frame(srv: RunningServer) -> None:
    client = await RawClient.open(srv.url())
    try:
        sub = {"op": "subscribe", "topic": "/fox/pose", "type": "geometry_msgs/PoseStamped"}
        await client.send({**sub, "compression": "cbor-raw", "id": "s1"})
        await until_async(lambda: srv.graph.subscribers("/fox/pose"), 10.0, "the subscription")
        pose = {
            "header": {"stamp": {"sec": 12, "nanosec": 34}, "frame_id": "map"},
            "pose": {"position": {"x": 1.5, "y": -2.0, "z": 0.25}},
        }
        srv.call(srv.graph.publish, "/fox/pose", pose)
        frame = await client.expect(lambda m: isinstance(m, bytes), what="a binary frame")
        body = cbor2.loads(frame)
        assert body["op"] == "publish" and body["topic"] == "/fox/pose"
        raw = body["msg"]
        assert set(raw) == {"bytes", "secs", "nsecs"} and isinstance(raw["bytes"], bytes)
        assert raw["secs"] > 1_600_000_000 and 0 <= raw["nsecs"] < 10**9
        decoded = codec_for("geometry_msgs/PoseStamped").decode(raw["bytes"])
        assert decoded["header"] == pose["header"]
        assert decoded["pose"]["position"] == {"x": 1.5, "y": -2.0, "z": 0.25}
        assert decoded["pose"]["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}
    finally:
        await client.ws.close()


async def test_cbor_raw_without_a_definition_is_a_status_error(srv: RunningServer) -> None:
    srv.call(srv.graph.advertise, "/fox/opaque", "vendor_msgs/Opaque")
    client = await RawClient.open(srv.url())
    try:
        await client.send(
            {"op": "subscribe", "topic": "/fox/opaque", "compression": "cbor-raw", "id": "s2"}
        )
        status = await client.expect_op("status", id="s2")
        assert status["level"] == "error" and "vendor_msgs/Opaque" in status["msg"]
    finally:
        await client.ws.close()


async def test_topics_and_raw_types_are_ros1_definitions(srv: RunningServer) -> None:
    srv.call(srv.graph.advertise, "/fox/image", "sensor_msgs/CompressedImage")
    client = await RawClient.open(srv.url())
    try:
        await client.send(
            {"op": "call_service", "service": "/rosapi/topics_and_raw_types", "id": "t"}
        )
        resp = await client.expect_op("service_response", id="t")
        values: dict[str, Any] = resp["values"]
        defs = dict(zip(values["topics"], values["typedefs_full_text"], strict=True))
        assert defs["/fox/image"] == definition("sensor_msgs/CompressedImage")
        assert "MSG: std_msgs/Header\nuint32 seq\ntime stamp" in defs["/fox/image"]
    finally:
        await client.ws.close()


def test_rosout_carries_log_lines_replies_and_task_events() -> None:
    graph = Graph()
    rosout = Rosout(graph)
    rosout.attach()
    seen: list[dict[str, Any]] = []
    graph.subscribe("/rosout", seen.append)
    try:
        assert graph.topic_type("/rosout") == "rosgraph_msgs/Log"
        logging.getLogger("server.recorder.test").warning("disk almost %s", "full")
        reply = {"text": "Battery low, returning home.", "level": "alert", "speak": True}
        graph.publish("/console/reply", reply, type="uav_console/Reply")
        task = {"drone": "uav2", "name": "goto", "state": "running", "detail": "marker 3"}
        graph.publish("/uav2/uav/task", task, type="uav_console/TaskStatus")
        graph.publish("/uav2/uav/task", dict(task, progress=0.5), type="uav_console/TaskStatus")
        graph.publish("/uav2/uav/task", dict(task, state="failed"), type="uav_console/TaskStatus")
    finally:
        rosout.detach()
    logging.getLogger("server").warning("after detach: not on /rosout")
    got = [(m["level"], m["name"], m["msg"]) for m in seen]
    assert got == [
        (WARN, "server.recorder.test", "disk almost full"),
        (ERROR, "console", "Battery low, returning home."),
        (INFO, "tasks", "uav2: task goto running: marker 3"),
        (WARN, "tasks", "uav2: task goto failed: marker 3"),
    ]
    assert seen[0]["function"] == "test_rosout_carries_log_lines_replies_and_task_events"
    for m in seen:  # every one serialises as ROS 1 (what cbor-raw and the recorder do)
        codec_for("rosgraph_msgs/Log").encode(m)
