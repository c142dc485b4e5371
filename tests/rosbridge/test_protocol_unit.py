"""The sans-I/O protocol, streams, values and encodings: no sockets, time passed in."""

from __future__ import annotations

import base64
import json
import math
from typing import Any

import cbor2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.rosbridge import ops
from server.rosbridge.encode import fragments, png_decode, png_encode
from server.rosbridge.errors import MessageError
from server.rosbridge.protocol import BridgeProtocol
from server.rosbridge.streams import SubParams, TopicStream, merge
from server.rosbridge.values import check_message, to_cbor_value, to_json_text


def statuses(p: BridgeProtocol) -> list[dict[str, Any]]:
    return [json.loads(f) for f in p.frames_to_send() if isinstance(f, str)]


def test_ops_decode_with_defaults() -> None:
    p = BridgeProtocol()
    [op] = p.receive_text('{"op":"subscribe","topic":"/a","id":"s"}', 0.0)
    assert op == ops.Subscribe(topic="/a", id="s")
    [op] = p.receive_text(
        '{"op":"advertise","topic":"/t","type":"std_msgs/msg/String","latch":true}', 0.0
    )
    assert op == ops.Advertise(topic="/t", type="std_msgs/String", latch=True)
    [op] = p.receive_text('{"op":"call_service","service":"s","args":[1,2],"timeout":0}', 0.0)
    assert op == ops.CallService(service="s", args=[1, 2], timeout_s=None)
    [op] = p.receive_text('{"op":"auth","mac":"tok"}', 0.0)
    assert op == ops.Auth(token="tok")
    assert p.frames_to_send() == []


@pytest.mark.parametrize(
    ("frame", "msg"),
    [
        ("nope", "invalid JSON"),
        ("3", "must be a JSON object"),
        ('{"id":"x"}', "frame has no 'op' field"),
        ('{"op":7}', "'op' must be a string"),
        ('{"op":"dance","id":"x"}', "unknown op 'dance'"),
        ('{"op":"publish","topic":"/a"}', "publish: field 'msg' is required"),
        ('{"op":"publish","topic":"/a","msg":[]}', "publish: field 'msg' must be an object"),
        ('{"op":"subscribe","topic":"/a","queue_length":-1}', "must be at least 0"),
        ('{"op":"subscribe","topic":"/a","fragment_size":0}', "must be at least 1"),
        ('{"op":"subscribe","topic":"/a","latch":1,"throttle_rate":true}', "wrong type"),
        ('{"op":"set_level","level":"loud"}', "level 'loud' is not one of"),
        ('{"op":"service_response","values":{}}', "'id' is required"),
        ('{"op":"fragment","id":"f","data":"x","num":2,"total":2}', "num 2 is not below"),
        ('{"op":"png","data":"!!"}', "png: cannot decode"),
    ],
)
def test_rejections_name_the_problem(frame: str, msg: str) -> None:
    p = BridgeProtocol()
    assert p.receive_text(frame, 0.0) == []
    [s] = statuses(p)
    assert s["op"] == "status" and s["level"] == "error" and msg in s["msg"]


def test_status_carries_id_and_respects_level() -> None:
    p = BridgeProtocol()
    p.receive_text('{"op":"bogus","id":"abc"}', 0.0)
    assert statuses(p)[0]["id"] == "abc"
    p.set_level("none")
    p.receive_text('{"op":"bogus","id":"abc"}', 0.0)
    assert statuses(p) == []


def test_fragments_reassemble_in_any_order_and_expire() -> None:
    text = json.dumps({"op": "publish", "topic": "/a", "msg": {"data": "x" * 50}})
    frames = fragments(text, 7, "f1")
    p = BridgeProtocol()
    out: list[ops.Op] = []
    for f in reversed(frames):
        out += p.receive_text(f, 0.0)
    assert out == [ops.Publish(topic="/a", msg={"data": "x" * 50})]
    # an incomplete message is dropped after the timeout, with a warning status
    p = BridgeProtocol(fragment_timeout_s=10.0)
    p.set_level("warning")
    p.receive_text(frames[0], 0.0)
    p.receive_text(frames[0].replace('"f1"', '"f2"'), 11.0)
    [s] = statuses(p)
    assert s["level"] == "warning" and "f1" in s["msg"]


def test_png_roundtrip_matches_rosbridge_layout() -> None:
    text = json.dumps({"op": "publish", "topic": "/a", "msg": {"data": "héllo"}})
    png = png_encode(text)
    assert png.startswith(b"\x89PNG") and png_decode(png).rstrip("\n") == text
    p = BridgeProtocol()
    frame = json.dumps({"op": "png", "data": base64.b64encode(png).decode()})
    assert p.receive_text(frame, 0.0) == [ops.Publish(topic="/a", msg={"data": "héllo"})]


def test_cbor_frames_in_and_out() -> None:
    p = BridgeProtocol()
    data = cbor2.dumps({"op": "subscribe", "topic": "/x"})
    assert p.receive_bytes(data, 0.0) == [ops.Subscribe(topic="/x")]
    msg = {"tags_xc": [1, 2], "tags_distance": [0.5], "batteryPercent": 50.0}
    [frame] = p.publish_frames(
        "/n", "", compression="cbor", msg=msg, type_name="ardrone_autonomy/Navdata"
    )
    decoded = cbor2.loads(frame)
    assert decoded["msg"]["tags_xc"].tag == 70  # uint32[] little-endian (rosbridge)
    assert decoded["msg"]["tags_distance"].tag == 85  # float32[]
    assert to_cbor_value("sensor_msgs/CompressedImage", {"data": "AQI="})["data"] == b"\x01\x02"


def test_outgoing_fragments_and_png_compression() -> None:
    p = BridgeProtocol()
    frames = p.publish_frames("/a", '{"data":"' + "z" * 100 + '"}', fragment_size=30)
    parts = [json.loads(f) for f in frames]
    assert all(f["op"] == "fragment" and f["total"] == len(parts) for f in parts)
    whole = json.loads("".join(f["data"] for f in parts))
    assert whole == {"op": "publish", "topic": "/a", "msg": {"data": "z" * 100}}
    [png] = p.publish_frames("/a", '{"data":"q"}', compression="png")
    inner = png_decode(base64.b64decode(json.loads(png)["data"]))
    assert json.loads(inner) == {"op": "publish", "topic": "/a", "msg": {"data": "q"}}


def test_service_response_always_has_values() -> None:
    p = BridgeProtocol()
    p.send_service_response("/s", "id1", "went wrong", False)
    [r] = statuses(p)
    assert r == {
        "op": "service_response",
        "service": "/s",
        "result": False,
        "id": "id1",
        "values": "went wrong",
    }


# -- values -------------------------------------------------------------------------------
def test_check_message_normalises() -> None:
    m = check_message(
        "geometry_msgs/PoseStamped",
        {"header": {"stamp": {"secs": 1, "nsecs": 2}}, "pose": {"position": {"x": 1}}},
        100.5,
    )
    assert m["header"] == {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": ""}
    assert m["pose"]["position"] == {"x": 1.0, "y": 0.0, "z": 0.0}
    assert m["pose"]["orientation"]["w"] == 0.0
    filled = check_message("std_msgs/Header", {}, 100.5)
    assert filled["stamp"] == {"sec": 100, "nanosec": 500_000_000}


@pytest.mark.parametrize(
    ("type_name", "msg", "error"),
    [
        ("std_msgs/Int32", {"data": 2**31}, "out of range for int32"),
        ("std_msgs/Int32", {"data": 1.5}, "must be an integer"),
        ("std_msgs/Bool", {"data": 1}, "must be true or false"),
        ("std_msgs/String", {"data": None}, "must be a string"),
        ("std_msgs/String", {"text": "x"}, "no field 'text'"),
        ("sensor_msgs/CompressedImage", {"data": "***"}, "must be base64"),
        ("sensor_msgs/CompressedImage", {"data": [256]}, "integers 0..255"),
        ("std_msgs/Header", {"stamp": {"sec": "1"}}, "stamp.sec must be an integer"),
        ("uav_console/MarkerArray", {"markers": [{"id": "a"}]}, "msg.markers[0].id"),
    ],
)
def test_check_message_errors(type_name: str, msg: dict[str, Any], error: str) -> None:
    with pytest.raises(MessageError, match=error.replace("[", r"\[").replace("]", r"\]")):
        check_message(type_name, msg, 0.0)


def test_json_out_handles_bytes_and_nan() -> None:
    text = to_json_text({"a": math.nan, "b": [math.inf, 1.0], "c": b"\x00\x01"})
    assert json.loads(text) == {"a": None, "b": [None, 1.0], "c": "AAE="}


# -- streams: throttle and queue as rosbridge_suite ---------------------------------------
def test_throttle_without_queue_drops_inside_window() -> None:
    s = TopicStream("/t", "std_msgs/Int32")
    s.add("a", SubParams(throttle_rate_ms=100))
    sent = [m for i, t in enumerate([0.0, 0.05, 0.099, 0.1, 0.15, 0.25]) for m in s.offer(i, t)]
    assert sent == [0, 3, 5] and s.dropped == 3


def test_queue_drains_one_per_window_and_drops_oldest() -> None:
    s = TopicStream("/t", "std_msgs/Int32")
    s.add("a", SubParams(throttle_rate_ms=100, queue_length=2))
    out = []
    for i in range(1, 6):
        out += s.offer(i, 0.0 + i * 0.001)
    assert out == [1] and s.dropped == 2
    assert s.next_due() == pytest.approx(0.101)
    assert s.poll(0.05) == []
    assert s.poll(0.101) == [4] and s.poll(0.15) == [] and s.poll(0.201) == [5]
    assert s.next_due() is None


def test_queue_without_throttle_sends_everything() -> None:
    s = TopicStream("/t", "std_msgs/Int32")
    s.add(None, SubParams(queue_length=3))
    assert s.offer(1, 0.0) == [1] and s.offer(2, 0.0) == [2]


def test_shared_stream_takes_minimums() -> None:
    merged = merge(
        [
            SubParams(200, 5, None, "none"),
            SubParams(50, 10, 100, "png"),
            SubParams(100, 2, 300, "cbor"),
        ]
    )
    assert merged == SubParams(50, 2, 100, "cbor")
    s = TopicStream("/t", "x/Y")
    s.add("a", SubParams(100, 0))
    s.add("b", SubParams(0, 0))
    assert s.offer(1, 0.0) == [1] and s.offer(2, 0.0) == [2]
    assert s.remove("b") and not s.remove("b")
    assert s.offer(3, 0.01) == []


# -- Hypothesis: anything in, ops or a status error out, never an exception ---------------
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=10), children, max_size=4)
    ),
    max_leaves=20,
)
op_names = st.sampled_from(
    [
        "publish",
        "subscribe",
        "unsubscribe",
        "advertise",
        "unadvertise",
        "call_service",
        "service_response",
        "advertise_service",
        "unadvertise_service",
        "set_level",
        "auth",
        "status",
        "fragment",
        "png",
        "x",
    ]
)
frames = st.dictionaries(
    st.sampled_from(
        [
            "op",
            "id",
            "topic",
            "type",
            "msg",
            "service",
            "args",
            "values",
            "result",
            "throttle_rate",
            "queue_length",
            "fragment_size",
            "compression",
            "level",
            "data",
            "num",
            "total",
            "latch",
            "timeout",
            "token",
        ]
    ),
    json_values,
    max_size=8,
).flatmap(lambda d: op_names.map(lambda o: {**d, "op": o}) | st.just(d))


def _answered(p: BridgeProtocol, result: list[ops.Op]) -> None:
    """Decoded ops are ops; anything sent back is a status message."""
    out = p.frames_to_send()
    assert all(type(o) in ops.Op.__args__ for o in result)  # type: ignore[attr-defined]
    for f in out:
        assert json.loads(f)["op"] == "status"


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=200))
def test_arbitrary_text_never_raises(text: str) -> None:
    p = BridgeProtocol()
    result = p.receive_text(text, 0.0)
    _answered(p, result)


@settings(max_examples=200, deadline=None)
@given(frames)
def test_arbitrary_json_frames_never_raise(frame: dict[str, Any]) -> None:
    p = BridgeProtocol()
    result = p.receive_text(json.dumps(frame), 0.0)
    out = p.frames_to_send()
    if frame.get("op") != "fragment":
        assert len(result) + len(out) >= 1  # every frame is answered: an op or a status
    for f in out:
        assert json.loads(f)["op"] == "status"


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=100))
def test_arbitrary_binary_never_raises(data: bytes) -> None:
    p = BridgeProtocol()
    p.receive_bytes(data, 0.0)
    p.frames_to_send()


async def test_json_cache_is_scoped_to_one_delivery_pass() -> None:
    import asyncio

    from server.rosbridge.context import JsonCache

    cache = JsonCache()
    msg: dict[str, Any] = {"data": 1}
    assert cache.text(msg) == '{"data":1}'
    msg["data"] = 2  # a publisher reusing its dict
    assert cache.text(msg) == '{"data":1}'  # same pass: shared text
    await asyncio.sleep(0)
    assert cache.text(msg) == '{"data":2}'  # next pass: fresh text
