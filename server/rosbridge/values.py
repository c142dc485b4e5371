"""Message values between the wire and the graph: checking, normalising and converting them.

In (client -> graph), :func:`check_message` validates a ``msg`` against its type in
``server.msgs`` the way rosbridge_suite's ``message_conversion.populate_instance`` does: missing
fields take their defaults, unknown fields and wrong types are errors naming the field path.
``uint8[]`` arrives as base64 (or a list) and travels in the graph as ``bytes``; a time arrives as
``{sec, nanosec}`` or ROS 1's ``{secs, nsecs}`` and travels as ``{sec, nanosec}``; a missing
``header.stamp`` is filled with the receive time.

Out (graph -> client), :func:`to_json_text` gives JSON with ``bytes`` as base64 and NaN/Inf as
``null`` (rosbridge_suite does the same since JSON has no NaN); :func:`to_cbor_value` gives the
value for CBOR compression with typed arrays tagged as in rosbridge_suite's ``cbor_conversion.py``
(draft-ietf-cbor-array-tags, little-endian: RFC 8746 tags 64-86).
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import re
import struct
from typing import Any

import cbor2

from server import msgs
from server.rosbridge.errors import MessageError, NotFoundError

_INT_RANGES: dict[str, tuple[int, int]] = {
    "byte": (0, 255),
    "char": (0, 255),
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
_FLOATS = {"float32", "float64"}
_TIME_TYPES = {"time", "duration", "builtin_interfaces/Time", "builtin_interfaces/Duration"}
_BYTES_TYPES = {"uint8", "char", "byte"}

# rosbridge_suite cbor_conversion.py TAGGED_ARRAY_FORMATS (little-endian typed-array tags).
CBOR_ARRAY_TAGS: dict[str, tuple[int, str]] = {
    "uint16": (69, "<{}H"),
    "uint32": (70, "<{}I"),
    "uint64": (71, "<{}Q"),
    "int8": (72, "{}b"),
    "int16": (77, "<{}h"),
    "int32": (78, "<{}i"),
    "int64": (79, "<{}q"),
    "float32": (85, "<{}f"),
    "float64": (86, "<{}d"),
}

_TYPE_RE = re.compile(r"^[A-Za-z][\w]*/(?:msg/|srv/)?[A-Za-z][\w]*$")


def normalise_type(name: str) -> str:
    """``std_msgs/msg/String`` (ROS 2 spelling) -> ``std_msgs/String``; checks the shape.

    Raises:
        NotFoundError: not of the form ``package/Type``.
    """
    if not isinstance(name, str) or not _TYPE_RE.match(name):
        raise NotFoundError(f"{name!r} is not a message type (expected package/Type)")
    parts = name.split("/")
    return f"{parts[0]}/{parts[-1]}"


def is_known_type(name: str) -> bool:
    return name in msgs.MESSAGES


def check_message(type_name: str, value: Any, now: float) -> dict[str, Any]:
    """Validate ``value`` as a ``type_name`` message and return its normalised copy.

    Types unknown to ``server.msgs`` are only checked to be JSON objects.

    Raises:
        MessageError: a field is unknown, has the wrong JSON type or is out of range.
    """
    if not isinstance(value, dict):
        raise MessageError(f"msg must be a JSON object for {type_name}, not {_kind(value)}")
    if type_name not in msgs.MESSAGES:
        return value
    return _check_struct(type_name, value, "msg", now)


def _check_struct(type_name: str, value: Any, path: str, now: float) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise MessageError(f"{path} must be an object ({type_name}), not {_kind(value)}")
    if type_name in _TIME_TYPES:
        return _check_time(value, path)
    fields = msgs.MESSAGES[type_name]
    names = {f for f, _ in fields}
    extra = sorted(set(value) - names)
    if extra:
        raise MessageError(f"{path} has no field {extra[0]!r} in {type_name}")
    out: dict[str, Any] = {}
    for fname, ftype in fields:
        fpath = f"{path}.{fname}"
        if fname not in value:
            if ftype == "std_msgs/Header":
                out[fname] = {"stamp": msgs.stamp(now), "frame_id": ""}
            elif ftype in _TIME_TYPES and fname == "stamp" and type_name == "std_msgs/Header":
                out[fname] = msgs.stamp(now)
            else:
                out[fname] = _default(ftype)
            continue
        out[fname] = _check_field(ftype, value[fname], fpath, now)
    return out


def _default(ftype: str) -> Any:
    if msgs.is_array(ftype):
        return b"" if msgs.base_type(ftype) in _BYTES_TYPES else []
    if ftype in msgs.PRIMITIVES:
        return msgs.PRIMITIVES[ftype]
    if ftype in _TIME_TYPES:
        return {"sec": 0, "nanosec": 0}
    return msgs.default_message(ftype)


def _check_field(ftype: str, value: Any, path: str, now: float) -> Any:
    if msgs.is_array(ftype):
        base = msgs.base_type(ftype)
        if base in _BYTES_TYPES:
            return _check_bytes(value, path)
        if not isinstance(value, list):
            raise MessageError(f"{path} must be an array ({ftype}), not {_kind(value)}")
        return [_check_field(base, v, f"{path}[{i}]", now) for i, v in enumerate(value)]
    if ftype in _INT_RANGES:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise MessageError(f"{path} must be an integer ({ftype}), not {_kind(value)}")
        lo, hi = _INT_RANGES[ftype]
        if not lo <= value <= hi:
            raise MessageError(f"{path} = {value} is out of range for {ftype} [{lo}, {hi}]")
        return value
    if ftype in _FLOATS:
        if value is None:  # we send NaN/Inf as null, so accept it back as NaN
            return math.nan
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise MessageError(f"{path} must be a number ({ftype}), not {_kind(value)}")
        return float(value)
    if ftype == "string":
        if not isinstance(value, str):
            raise MessageError(f"{path} must be a string, not {_kind(value)}")
        return value
    if ftype == "bool":
        if not isinstance(value, bool):
            raise MessageError(f"{path} must be true or false, not {_kind(value)}")
        return value
    if ftype in _TIME_TYPES:
        return _check_time(value, path)
    if ftype in msgs.MESSAGES:
        return _check_struct(ftype, value, path, now)
    raise MessageError(f"{path} has type {ftype}, which this server does not know")


def _check_time(value: Any, path: str) -> dict[str, int]:
    if not isinstance(value, dict):
        raise MessageError(f"{path} must be a time object {{sec, nanosec}}, not {_kind(value)}")
    if set(value) <= {"sec", "nanosec"}:
        sec, nsec = value.get("sec", 0), value.get("nanosec", 0)
    elif set(value) <= {"secs", "nsecs"}:
        sec, nsec = value.get("secs", 0), value.get("nsecs", 0)
    else:
        raise MessageError(f"{path} must have fields sec and nanosec (or secs and nsecs)")
    for name, v in (("sec", sec), ("nanosec", nsec)):
        if isinstance(v, bool) or not isinstance(v, int):
            raise MessageError(f"{path}.{name} must be an integer, not {_kind(v)}")
    if not -(2**31) <= sec < 2**31 or not 0 <= nsec < 2**32:
        raise MessageError(f"{path} is out of range for a time")
    return {"sec": sec, "nanosec": nsec}


def _check_bytes(value: Any, path: str) -> bytes:
    if isinstance(value, str):
        try:
            return base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError) as exc:
            raise MessageError(f"{path} must be base64 (uint8[]): {exc}") from exc
    if isinstance(value, list):
        if not all(isinstance(b, int) and not isinstance(b, bool) and 0 <= b <= 255 for b in value):
            raise MessageError(f"{path} must be a list of integers 0..255 (uint8[])")
        return bytes(value)
    if isinstance(value, bytes | bytearray):
        return bytes(value)
    raise MessageError(f"{path} must be base64 text or a list (uint8[]), not {_kind(value)}")


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


# -- out ----------------------------------------------------------------------------------
def to_json_text(value: Any) -> str:
    """Compact JSON for ``value``: ``bytes`` -> base64, NaN/Inf -> null.

    The fast path is one C-level ``json.dumps``; only values holding bytes or non-finite floats
    take the slower sanitising walk.
    """
    try:
        return json.dumps(value, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError):
        return json.dumps(to_json_value(value), separators=(",", ":"), allow_nan=False)


def to_json_value(value: Any) -> Any:
    """``value`` with bytes as base64 text and non-finite floats as None; tuples as lists."""
    if isinstance(value, dict):
        return {str(k): to_json_value(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_json_value(v) for v in value]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    if value is None or isinstance(value, bool | int | str):
        return value
    raise TypeError(f"cannot send a {type(value).__name__} in a message")


def to_cbor_value(type_name: str | None, value: Any) -> Any:
    """``value`` for CBOR: uint8[] as a byte string, numeric arrays as tagged typed arrays."""
    fields = msgs.MESSAGES.get(type_name or "")
    if not isinstance(value, dict) or fields is None:
        return _cbor_plain(value)
    out: dict[str, Any] = {}
    types = dict(fields)
    for k, v in value.items():
        ftype = types.get(k)
        if ftype is None:
            out[k] = _cbor_plain(v)
        elif msgs.is_array(ftype):
            out[k] = _cbor_array(msgs.base_type(ftype), v)
        elif ftype in msgs.MESSAGES:
            out[k] = to_cbor_value(ftype, v)
        else:
            out[k] = _cbor_plain(v)
    return out


def _cbor_array(base: str, v: Any) -> Any:
    if base in _BYTES_TYPES:
        if isinstance(v, str):
            return base64.b64decode(v)
        return bytes(v)
    tag = CBOR_ARRAY_TAGS.get(base)
    if tag is not None and isinstance(v, list):
        try:
            return cbor2.CBORTag(tag[0], struct.pack(tag[1].format(len(v)), *v))
        except struct.error:
            return _cbor_plain(v)
    if base in msgs.MESSAGES and isinstance(v, list):
        return [to_cbor_value(base, x) for x in v]
    return _cbor_plain(v)


def _cbor_plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _cbor_plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_cbor_plain(v) for v in value]
    if isinstance(value, bytearray | memoryview):
        return bytes(value)
    return value
