"""How a graph type is written to MCAP: schema name, schema encoding and data, message encoding.

Foxglove decodes ``ros1msg`` schemas (the full ``gendeps --cat`` text, as rosapi's
``topics_and_raw_types`` returns it) with ``ros1`` messages, and shows
``sensor_msgs/CompressedImage`` in its Image panel. A type with no definition (a client may
publish any ``pkg/Type`` whose fields the graph does not know) is written as JSON with a
permissive JSON Schema, which Foxglove also decodes: nothing on the graph is left out.
(MCAP spec, "Well-known encodings" / registry: ``ros1``+``ros1msg``, ``json``+``jsonschema``.)
"""

from __future__ import annotations

import base64
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from server.ros1 import codec_for, has_definition

ROS1 = "ros1"
JSON = "json"


@dataclass(frozen=True)
class ChannelFormat:
    schema_name: str
    schema_encoding: str  # "ros1msg" or "jsonschema"
    schema_data: bytes
    message_encoding: str  # "ros1" or "json"
    encode: Callable[[dict[str, Any]], bytes]
    decode: Callable[[bytes], dict[str, Any]]


def _json_default(value: Any) -> Any:
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    raise TypeError(f"{type(value).__name__} is not JSON")


def _json_encode(msg: dict[str, Any]) -> bytes:
    return json.dumps(msg, default=_json_default, separators=(",", ":")).encode()


def _json_decode(data: bytes) -> dict[str, Any]:
    """One JSON message read back from a file (raises ``ValueError`` for anything else)."""
    try:
        value = json.loads(data)
    except RecursionError as exc:  # [[[[… deeper than the interpreter's stack
        raise ValueError("a JSON message nested too deeply") from exc
    if not isinstance(value, dict):
        raise ValueError("a JSON message must be an object")
    return value


def format_for(type_name: str) -> ChannelFormat:
    """The MCAP format of ``type_name`` (ROS 1 when it has a full definition, else JSON)."""
    if has_definition(type_name):
        codec = codec_for(type_name)
        return ChannelFormat(
            type_name, "ros1msg", codec.definition.encode(), ROS1, codec.encode, codec.decode
        )
    schema = {"title": type_name, "type": "object"}
    return ChannelFormat(
        type_name, "jsonschema", json.dumps(schema).encode(), JSON, _json_encode, _json_decode
    )


def decoder_for(
    schema_name: str, schema_encoding: str, schema_data: bytes, message_encoding: str
) -> Callable[[bytes], dict[str, Any]]:
    """A decoder for a channel read back from a file (ours or another tool's).

    Raises:
        ValueError: an encoding this reader cannot decode.
    """
    if message_encoding == JSON:
        return _json_decode
    if message_encoding == ROS1 and schema_encoding == "ros1msg" and has_definition(schema_name):
        codec = codec_for(schema_name)
        if codec.definition.encode() == schema_data:
            return codec.decode
        raise ValueError(f"{schema_name}: the file's ROS 1 definition differs from this version's")
    raise ValueError(f"cannot decode {message_encoding} messages of {schema_name}")
