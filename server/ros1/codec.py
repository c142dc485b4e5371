"""ROS 1 binary serialisation of graph messages, compiled once per type from its definition.

Wire format (ROS wiki "msg" serialisation, roscpp ``serialization.h``): little-endian
primitives; ``bool`` one byte; ``string`` a ``uint32`` byte length then UTF-8; ``time`` and
``duration`` two 32-bit words (secs, nsecs); a variable-length array a ``uint32`` count then the
elements; ``uint8[]``/``char[]``/``byte[]`` the raw bytes. Nested messages are inlined.

Graph messages are ROS 2-shaped dicts (``{sec, nanosec}`` stamps, headers without ``seq``):
:meth:`MessageCodec.encode` takes them (ROS 1's ``{secs, nsecs}`` too, a missing field as its
default) and :meth:`MessageCodec.decode` gives them back in the same shape, so
encode-then-decode is the identity on what the graph carries. ``uint8[]`` may be ``bytes``,
base64 text (as the vehicle node publishes camera JPEGs) or a list of ints; it decodes to
``bytes``.
"""

from __future__ import annotations

import base64
import binascii
import functools
import math
import struct
from collections.abc import Callable, Mapping
from typing import Any

from server import msgs
from server.ros1.definitions import PRIMITIVES, definition, dependencies, ros1_fields
from server.ros1.errors import DecodeError, EncodeError

Encoder = Callable[[bytearray, Any, str], None]
Decoder = Callable[[memoryview, int], tuple[Any, int]]

_U32 = struct.Struct("<I")
_NUMBERS: dict[str, tuple[struct.Struct, int, int] | tuple[struct.Struct, None, None]] = {
    "bool": (struct.Struct("<B"), 0, 1),
    "int8": (struct.Struct("<b"), -(2**7), 2**7 - 1),
    "uint8": (struct.Struct("<B"), 0, 2**8 - 1),
    "byte": (struct.Struct("<B"), 0, 2**8 - 1),
    "char": (struct.Struct("<B"), 0, 2**8 - 1),
    "int16": (struct.Struct("<h"), -(2**15), 2**15 - 1),
    "uint16": (struct.Struct("<H"), 0, 2**16 - 1),
    "int32": (struct.Struct("<i"), -(2**31), 2**31 - 1),
    "uint32": (struct.Struct("<I"), 0, 2**32 - 1),
    "int64": (struct.Struct("<q"), -(2**63), 2**63 - 1),
    "uint64": (struct.Struct("<Q"), 0, 2**64 - 1),
    "float32": (struct.Struct("<f"), None, None),
    "float64": (struct.Struct("<d"), None, None),
}
_BYTE_ARRAYS = {"uint8", "char", "byte"}


class MessageCodec:
    """Encoder and decoder of one message type (get one with :func:`codec_for`)."""

    def __init__(self, type_name: str) -> None:
        self.type_name = type_name
        self.definition = definition(type_name)
        self._encode, self._decode = _compile(type_name)

    def encode(self, msg: Mapping[str, Any]) -> bytes:
        """The ROS 1 serialisation of ``msg``.

        Raises:
            EncodeError: a field has a value its type cannot hold (the message names it).
        """
        out = bytearray()
        self._encode(out, msg, self.type_name)
        return bytes(out)

    def decode(self, data: bytes | bytearray | memoryview) -> dict[str, Any]:
        """The graph message serialised in ``data``.

        Raises:
            DecodeError: ``data`` is not exactly one message of this type.
        """
        view = memoryview(data)
        try:
            value, end = self._decode(view, 0)
        except (struct.error, IndexError) as exc:
            raise DecodeError(f"{self.type_name}: truncated message ({len(view)} bytes)") from exc
        except UnicodeDecodeError as exc:
            raise DecodeError(f"{self.type_name}: a string is not UTF-8: {exc}") from exc
        if end != len(view):
            raise DecodeError(f"{self.type_name}: {len(view) - end} bytes left after the message")
        return value  # type: ignore[no-any-return]


@functools.cache
def codec_for(type_name: str) -> MessageCodec:
    """The (cached) codec of ``type_name``.

    Raises:
        UnknownType: it, or a type it uses, has no ROS 1 definition.
    """
    return MessageCodec(type_name)


# -- compilation --------------------------------------------------------------------------
def _compile(type_name: str) -> tuple[Encoder, Decoder]:
    dependencies(type_name)  # raises UnknownType with the path of what is missing
    encoders: dict[str, Encoder] = {}
    decoders: dict[str, Decoder] = {}
    # Build from the leaves up so a message's fields find their nested codecs.
    for dep in reversed(dependencies(type_name)):
        encoders[dep], decoders[dep] = _compile_message(dep, encoders, decoders)
    return encoders[type_name], decoders[type_name]


def _compile_message(
    type_name: str, encoders: dict[str, Encoder], decoders: dict[str, Decoder]
) -> tuple[Encoder, Decoder]:
    steps: list[tuple[Encoder, Decoder]] = []
    run: list[tuple[str, str]] = []  # consecutive numeric scalars, packed with one Struct
    # ROS 1 Header's seq is not in the graph's (ROS 2-shaped) header: written, not read back.
    hidden = {"seq"} if type_name == "std_msgs/Header" else set()
    for fname, ftype in [*ros1_fields(type_name), ("", "")]:
        if ftype in _NUMBERS and ftype != "bool":
            run.append((fname, ftype))
            continue
        if run:
            steps.append(_run_step(run, hidden))
            run = []
        if fname:
            steps.append(_field_step(fname, ftype, encoders, decoders, fname in hidden))

    def encode(out: bytearray, value: Any, path: str) -> None:
        if not isinstance(value, Mapping):
            raise EncodeError(f"{path}: expected a {type_name} object, got {_kind(value)}")
        for enc, _dec in steps:
            enc(out, value, path)

    def decode(view: memoryview, pos: int) -> tuple[Any, int]:
        result: dict[str, Any] = {}
        for _enc, dec in steps:
            pos = dec(view, pos, result)  # type: ignore[call-arg,assignment]
        return result, pos

    return encode, decode


def _field_step(
    fname: str,
    ftype: str,
    encoders: dict[str, Encoder],
    decoders: dict[str, Decoder],
    hidden: bool,
) -> tuple[Any, Any]:
    enc, dec, default = _field_codec(ftype, encoders, decoders)

    def encode(out: bytearray, value: Mapping[str, Any], path: str) -> None:
        item = value.get(fname)
        enc(out, default() if item is None else item, f"{path}.{fname}")

    def decode(view: memoryview, pos: int, result: dict[str, Any]) -> int:
        item, pos = dec(view, pos)
        if not hidden:
            result[fname] = item
        return pos

    return encode, decode


def _run_step(run: list[tuple[str, str]], hidden: set[str]) -> tuple[Any, Any]:
    """Consecutive numeric fields as one ``struct`` call (the common case, several times
    faster); a value ``struct`` refuses goes through the per-field codecs for a precise
    error (or, for a float32 overflow, ROS's inf)."""
    names = [n for n, _ in run]
    defaults = [msgs.PRIMITIVES[t] for _, t in run]
    st = struct.Struct("<" + "".join(_NUMBERS[t][0].format[1:] for _, t in run))
    singles = [_primitive(t)[0] for _, t in run]
    keep = [n not in hidden for n in names]

    def encode(out: bytearray, value: Mapping[str, Any], path: str) -> None:
        vals = [value.get(n) for n in names]
        vals = [d if v is None else v for v, d in zip(vals, defaults, strict=True)]
        try:
            out += st.pack(*vals)
        except (struct.error, OverflowError, TypeError):
            for n, enc, v in zip(names, singles, vals, strict=True):
                enc(out, v, f"{path}.{n}")

    def decode(view: memoryview, pos: int, result: dict[str, Any]) -> int:
        for n, k, v in zip(names, keep, st.unpack_from(view, pos), strict=True):
            if k:
                result[n] = v
        return pos + st.size

    return encode, decode


def _field_codec(
    ftype: str, encoders: dict[str, Encoder], decoders: dict[str, Decoder]
) -> tuple[Encoder, Decoder, Callable[[], Any]]:
    base = msgs.base_type(ftype)
    if ftype == base:
        if base in PRIMITIVES:
            return (*_primitive(base), lambda: _default(base))
        return encoders[base], decoders[base], dict
    inner = ftype[len(base) + 1 : -1]
    fixed = int(inner) if inner else None
    if base in _BYTE_ARRAYS:
        return (*_byte_array(fixed), bytes)
    if base in PRIMITIVES:
        enc, dec = _primitive(base)
    else:
        enc, dec = encoders[base], decoders[base]
    return (*_array(enc, dec, fixed), list)


def _default(base: str) -> Any:
    if base in ("time", "duration"):
        return {"sec": 0, "nanosec": 0}
    return msgs.PRIMITIVES[base]


def _kind(value: Any) -> str:
    return type(value).__name__


def _primitive(base: str) -> tuple[Encoder, Decoder]:
    if base == "string":
        return _enc_string, _dec_string
    if base in ("time", "duration"):
        return _time_codec(signed=base == "duration")
    st, lo, hi = _NUMBERS[base]
    size = st.size
    pack_into = st.pack_into
    unpack_from = st.unpack_from
    if lo is None:

        def enc_float(out: bytearray, value: Any, path: str) -> None:
            if value is None:
                value = math.nan
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise EncodeError(f"{path}: expected a number, got {_kind(value)}")
            start = len(out)
            out.extend(bytes(size))
            try:
                pack_into(out, start, value)
            except (OverflowError, struct.error):
                # float32 overflow: ROS C++ would store inf.
                pack_into(out, start, math.copysign(math.inf, value))

        def dec_float(view: memoryview, pos: int) -> tuple[Any, int]:
            return unpack_from(view, pos)[0], pos + size

        return enc_float, dec_float
    is_bool = base == "bool"

    def enc_int(out: bytearray, value: Any, path: str) -> None:
        if not isinstance(value, int) or (isinstance(value, bool) and not is_bool):
            raise EncodeError(f"{path}: expected an integer ({base}), got {_kind(value)}")
        if not lo <= value <= hi:  # type: ignore[operator]
            raise EncodeError(f"{path}: {value} is out of range for {base}")
        start = len(out)
        out.extend(bytes(size))
        pack_into(out, start, int(value))

    def dec_int(view: memoryview, pos: int) -> tuple[Any, int]:
        value = unpack_from(view, pos)[0]
        return (bool(value) if is_bool else value), pos + size

    return enc_int, dec_int


def _enc_string(out: bytearray, value: Any, path: str) -> None:
    if not isinstance(value, str):
        raise EncodeError(f"{path}: expected a string, got {_kind(value)}")
    data = value.encode("utf-8", "surrogatepass")
    out += _U32.pack(len(data))
    out += data


def _dec_string(view: memoryview, pos: int) -> tuple[Any, int]:
    (n,) = _U32.unpack_from(view, pos)
    end = pos + 4 + n
    if end > len(view):
        raise IndexError("string runs past the end")
    return bytes(view[pos + 4 : end]).decode("utf-8"), end


def _time_codec(*, signed: bool) -> tuple[Encoder, Decoder]:
    st = struct.Struct("<iI" if signed else "<II")

    def enc(out: bytearray, value: Any, path: str) -> None:
        if not isinstance(value, Mapping):
            raise EncodeError(f"{path}: expected a time {{sec, nanosec}}, got {_kind(value)}")
        sec = value.get("sec", value.get("secs", 0))
        nsec = value.get("nanosec", value.get("nsecs", 0))
        try:
            out += st.pack(sec, nsec)
        except struct.error as exc:
            raise EncodeError(f"{path}: not a time: {exc}") from exc

    def dec(view: memoryview, pos: int) -> tuple[Any, int]:
        sec, nsec = st.unpack_from(view, pos)
        return {"sec": sec, "nanosec": nsec}, pos + 8

    return enc, dec


def _byte_array(fixed: int | None) -> tuple[Encoder, Decoder]:
    def enc(out: bytearray, value: Any, path: str) -> None:
        if isinstance(value, str):
            try:
                data = base64.b64decode(value, validate=True)
            except (binascii.Error, ValueError) as exc:
                raise EncodeError(f"{path}: not base64: {exc}") from exc
        elif isinstance(value, bytes | bytearray | memoryview):
            data = bytes(value)
        elif isinstance(value, list):
            try:
                data = bytes(value)
            except (TypeError, ValueError) as exc:
                raise EncodeError(f"{path}: not a list of bytes: {exc}") from exc
        else:
            raise EncodeError(f"{path}: expected bytes, got {_kind(value)}")
        if fixed is None:
            out += _U32.pack(len(data))
        elif len(data) != fixed:
            raise EncodeError(f"{path}: expected {fixed} bytes, got {len(data)}")
        out += data

    def dec(view: memoryview, pos: int) -> tuple[Any, int]:
        if fixed is None:
            (n,) = _U32.unpack_from(view, pos)
            pos += 4
        else:
            n = fixed
        if pos + n > len(view):
            raise IndexError("byte array runs past the end")
        return bytes(view[pos : pos + n]), pos + n

    return enc, dec


def _array(item_enc: Encoder, item_dec: Decoder, fixed: int | None) -> tuple[Encoder, Decoder]:
    def enc(out: bytearray, value: Any, path: str) -> None:
        if not isinstance(value, list | tuple):
            raise EncodeError(f"{path}: expected a list, got {_kind(value)}")
        if fixed is None:
            out += _U32.pack(len(value))
        elif len(value) != fixed:
            raise EncodeError(f"{path}: expected {fixed} items, got {len(value)}")
        for i, item in enumerate(value):
            item_enc(out, item, f"{path}[{i}]")

    def dec(view: memoryview, pos: int) -> tuple[Any, int]:
        if fixed is None:
            (n,) = _U32.unpack_from(view, pos)
            pos += 4
            if n > len(view) - pos:  # each element takes at least one byte
                raise IndexError("array count runs past the end")
        else:
            n = fixed
        items = []
        for _ in range(n):
            item, pos = item_dec(view, pos)
            items.append(item)
        return items, pos

    return enc, dec
