"""ROS 1 definitions and serialisation of every graph type (server/ros1)."""

from __future__ import annotations

import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server import msgs
from server.ros1 import DecodeError, EncodeError, UnknownType, codec_for, definition
from server.ros1.definitions import ros1_fields

ALL_TYPES = sorted(t for t in msgs.MESSAGES if not t.startswith("builtin_interfaces/"))

_INTS = {
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 255),
    "byte": (0, 255),
    "char": (0, 255),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}


def _value(ftype: str, depth: int = 0) -> st.SearchStrategy[Any]:
    base = msgs.base_type(ftype)
    if ftype.endswith("[]"):
        if base in ("uint8", "char", "byte"):
            return st.binary(max_size=64)
        return st.lists(_value(base, depth + 1), max_size=3)
    if msgs.array_length(ftype) > 0:  # T[N]: exactly N
        n = msgs.array_length(ftype)
        if base in ("uint8", "char", "byte"):
            return st.binary(min_size=n, max_size=n)
        return st.lists(_value(base, depth + 1), min_size=n, max_size=n)
    if base in _INTS:
        lo, hi = _INTS[base]
        return st.integers(lo, hi)
    if base == "bool":
        return st.booleans()
    if base == "float32":
        return st.floats(width=32, allow_nan=False)
    if base == "float64":
        return st.floats(allow_nan=False)
    if base == "string":
        return st.text(max_size=20)
    if base in ("time", "duration"):
        return st.fixed_dictionaries(
            {"sec": st.integers(0, 2**31 - 1), "nanosec": st.integers(0, 999_999_999)}
        )
    return _message(base, depth + 1)


def _message(type_name: str, depth: int = 0) -> st.SearchStrategy[dict[str, Any]]:
    fields = {name: _value(ftype, depth) for name, ftype in ros1_fields(type_name) if name != "seq"}
    return st.fixed_dictionaries(fields)


@pytest.mark.parametrize("type_name", ALL_TYPES)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_encode_then_decode_is_the_identity(type_name: str, data: st.DataObject) -> None:
    msg = data.draw(_message(type_name))
    codec = codec_for(type_name)
    assert codec.decode(codec.encode(msg)) == msg


@pytest.mark.parametrize("type_name", ALL_TYPES)
@settings(max_examples=60, deadline=None)
@given(blob=st.binary(max_size=200))
def test_garbage_decodes_or_raises_decode_error(type_name: str, blob: bytes) -> None:
    try:
        value = codec_for(type_name).decode(blob)
    except DecodeError:
        return
    assert isinstance(value, dict)


def test_header_and_image_definitions_are_ros1() -> None:
    text = definition("sensor_msgs/CompressedImage")
    assert text.splitlines()[:3] == ["std_msgs/Header header", "string format", "uint8[] data"]
    assert "=" * 80 + "\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id" in text
    log = definition("rosgraph_msgs/Log")
    assert log.startswith("byte DEBUG=1\nbyte INFO=2\nbyte WARN=4\nbyte ERROR=8\nbyte FATAL=16\n")
    nested = definition("uav_console/FleetStatus")
    assert nested.count("MSG: ") == 3  # Header, DroneStatus, Point: each once


def test_wire_bytes_match_the_ros1_layout() -> None:
    # std_msgs/Header: seq u32, stamp (secs u32, nsecs u32), frame_id (u32 length + bytes)
    msg = {"header": {"stamp": {"sec": 7, "nanosec": 9}, "frame_id": "map"}, "format": "jpeg"}
    msg["data"] = b"\xff\xd8"
    out = codec_for("sensor_msgs/CompressedImage").encode(msg)
    expected = struct.pack("<III", 0, 7, 9) + struct.pack("<I", 3) + b"map"
    expected += struct.pack("<I", 4) + b"jpeg" + struct.pack("<I", 2) + b"\xff\xd8"
    assert out == expected
    # ROS 1 spelling of a time and base64 bytes (as the vehicle node publishes JPEGs) too
    msg["header"]["stamp"] = {"secs": 7, "nsecs": 9}
    msg["data"] = "/9g="
    assert codec_for("sensor_msgs/CompressedImage").encode(msg) == expected


def test_bad_messages_name_the_field() -> None:
    codec = codec_for("uav_console/MarkerArray")
    with pytest.raises(EncodeError, match=r"markers\[0\]\.id"):
        codec.encode({"markers": [{"id": "three"}]})
    with pytest.raises(EncodeError, match="out of range"):
        codec_for("std_msgs/Int32").encode({"data": 2**40})
    with pytest.raises(DecodeError, match="left after"):
        codec_for("std_msgs/Int32").decode(b"\x00" * 5)
    with pytest.raises(UnknownType, match="no/Such"):
        codec_for("no/Such")
