"""What decoding one inbound frame may cost, and the decoders that keep to it (sans-I/O, pure).

A frame is judged before the expensive part of its decoding, from what it says about itself:

- ``png`` (ROSBRIDGE_PROTOCOL.md §3.3.2): the PNG's header (signature and IHDR, the first 33
  bytes, i.e. the first 44 characters of its base64) gives width, height and bit depth; an
  image over :attr:`DecodeBudget.max_png_pixels` or whose pixel rows would unpack to more than
  :attr:`DecodeBudget.max_png_bytes` is refused before anything is inflated. Inflating is then
  incremental with a byte budget (the header's row size × height, exactly: a zlib bomb behind a
  small header stops there), and the rows are handled in C over the whole buffer (one slice
  deletion drops the filter bytes), so the cost is linear in the bytes, not per row (sliced row
  by row in Python, a 1-pixel wide image of 16 MB took 11.8 s, 24× a 1000-pixel wide one).
- JSON text inside a PNG: the number of values it can hold is bounded by its ``,`` ``:`` ``[``
  ``{`` characters; more than :attr:`DecodeBudget.max_values` of them and it is refused before
  ``json.loads`` (a text of small numbers parses ~100× slower a byte than one long string, so
  a budget in bytes alone would not bound the work).
- Any decoded frame: at most :attr:`DecodeBudget.max_values` values (:func:`count_values`),
  so what a worker hands back to the event loop costs it little to take in and check.

The defaults keep a frame's decoding under ``max_work_s`` (50 ms) on the machines this runs on
(``bench/attacks.py`` measures the largest PNG within budget); :func:`png_text` also stops when
its clock says the work went over ``max_work_s``, a backstop for anything the header misjudges.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import re
import struct
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cbor2

from server.rosbridge.errors import BudgetExceeded

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Signature (8) + IHDR's length and type (8) + its 13 bytes of data + CRC (4): PNG spec §5.6
# (IHDR comes first).
PNG_HEADER_BYTES = 33
PNG_HEADER_B64_CHARS = 44  # base64 of 33 bytes, without padding
# rosbridge_suite's encoder (pngcompression.py) writes 8-bit RGB, non-interlaced: PNG spec §11.2.2
# colour type 2, bit depth 8, compression 0, filter method 0, interlace 0.
RGB = 2
BYTES_PER_PIXEL = 3
INFLATE_STEP = 1 << 20  # bytes of pixels inflated between checks of the work clock


class PngError(ValueError):
    """The data is not a PNG of the shape rosbridge sends, or is truncated."""


@dataclass(frozen=True)
class DecodeBudget:
    """What one inbound frame may cost to decode.

    Attributes:
        max_png_pixels: width × height of a ``png`` frame's image (4 megapixels).
        max_png_bytes: its pixel rows, unpacked (filter bytes included); 4 MiB of text is
            ~1.4 megapixels of rosbridge's RGB layout.
        max_png_chunks: PNG chunks in one image (ours has one IDAT, libpng's a few a megabyte;
            ~900 000 one-byte IDAT chunks froze the loop for 12 s when they were joined one by
            one).
        max_values: values (numbers, strings, array elements, object members …) in one decoded
            frame; a frame with more is refused (the event loop takes the result in and checks
            it, so this bounds its share).
        max_work_s: the decoding work one frame may cost, in seconds of the worker's CPU.
    """

    max_png_pixels: int = 4_000_000
    max_png_bytes: int = 4 << 20
    max_png_chunks: int = 4096
    max_values: int = 1 << 16
    max_work_s: float = 0.050


@dataclass(frozen=True)
class PngHeader:
    """A PNG's IHDR (PNG spec §11.2.2)."""

    width: int
    height: int
    bit_depth: int
    colour_type: int
    interlace: int

    @property
    def stride(self) -> int:
        """Bytes of one unpacked row: the filter byte, then the pixels."""
        return 1 + self.width * BYTES_PER_PIXEL

    @property
    def raw_bytes(self) -> int:
        return self.height * self.stride


def png_header(head: bytes) -> PngHeader:
    """The header of a PNG from its first :data:`PNG_HEADER_BYTES` bytes (more are ignored).

    Raises:
        PngError: not a PNG, IHDR not first, or not 8-bit RGB, non-interlaced.
    """
    if len(head) < PNG_HEADER_BYTES or not head.startswith(PNG_SIGNATURE):
        raise PngError("not a PNG file")
    length, kind = struct.unpack_from(">I4s", head, 8)
    if kind != b"IHDR" or length != 13:
        raise PngError("PNG does not start with its IHDR chunk")
    width, height, depth, colour, compression, filtering, interlace = struct.unpack_from(
        ">IIBBBBB", head, 16
    )
    if not (0 < width < 2**31 and 0 < height < 2**31):  # PNG spec §11.2.2
        raise PngError(f"PNG size {width}×{height} is not valid")
    if depth != 8 or colour != RGB or compression != 0 or filtering != 0 or interlace != 0:
        raise PngError(
            f"PNG is bit depth {depth}, colour type {colour}, interlace {interlace}: only 8-bit "
            "RGB, non-interlaced (as rosbridge's encoder writes) is accepted"
        )
    return PngHeader(width, height, depth, colour, interlace)


def check_png_budget(header: PngHeader, budget: DecodeBudget) -> None:
    """Refuse an image that would cost more than the budget, before anything is inflated.

    Raises:
        BudgetExceeded: over ``max_png_pixels`` or ``max_png_bytes``.
    """
    pixels = header.width * header.height
    size = f"{header.width}×{header.height} pixels"
    if pixels > budget.max_png_pixels:
        raise BudgetExceeded(
            f"png: an image of {size} is over the decoding budget of "
            f"{budget.max_png_pixels / 1e6:g} megapixels a frame; refused before decoding"
        )
    if header.raw_bytes > budget.max_png_bytes:
        raise BudgetExceeded(
            f"png: an image of {size} unpacks to {header.raw_bytes} bytes, over the decoding "
            f"budget of {budget.max_png_bytes} bytes a frame; refused before decoding"
        )


def png_header_of_base64(data: str) -> PngHeader:
    """The header of the PNG whose base64 is ``data``, from its first 44 characters only.

    Raises:
        PngError: as :func:`png_header`, or ``data`` does not start with valid base64.
    """
    try:
        head = base64.b64decode(data[:PNG_HEADER_B64_CHARS], validate=True)
    except (binascii.Error, ValueError) as exc:
        raise PngError(f"not base64: {exc}") from exc
    return png_header(head)


def png_text(
    png: bytes,
    budget: DecodeBudget,
    *,
    clock: Callable[[], float] = time.thread_time,
) -> str:
    """The text in a rosbridge PNG (the inverse of ``encode.png_encode``), within ``budget``.

    Linear in the input: the header is checked first (:func:`check_png_budget`), IDAT bodies
    are fed one by one to one incremental inflater that stops at the size the header announces,
    chunks are capped, and the filter bytes are checked and dropped by slicing the whole buffer.
    ``clock`` (seconds of work; the worker thread's CPU time by default) is read between steps.

    Raises:
        PngError: malformed, truncated, more data than the header announces, a row filter
            other than 0 (None), or not UTF-8.
        BudgetExceeded: over the budget (header, or ``max_work_s`` by ``clock``).
    """
    started = clock()
    header = png_header(png[:PNG_HEADER_BYTES])
    check_png_budget(header, budget)
    expected = header.raw_bytes
    view = memoryview(png)
    pos, chunks = len(PNG_SIGNATURE), 0
    inflater = zlib.decompressobj()
    out = bytearray()
    while pos < len(png):
        if pos + 12 > len(png):
            raise PngError("truncated PNG chunk header")
        (length,) = struct.unpack_from(">I", png, pos)
        kind = bytes(view[pos + 4 : pos + 8])
        end = pos + 8 + length
        if end + 4 > len(png):
            raise PngError(f"truncated PNG chunk {kind!r}")
        chunks += 1
        if chunks > budget.max_png_chunks:
            raise PngError(f"PNG has more than {budget.max_png_chunks} chunks")
        if kind == b"IDAT":
            data: bytes | memoryview = view[pos + 8 : end]
            while data:
                want = min(INFLATE_STEP, expected + 1 - len(out))
                try:
                    out += inflater.decompress(data, want)
                except zlib.error as exc:
                    raise PngError(f"PNG pixels are not valid zlib data: {exc}") from exc
                data = inflater.unconsumed_tail
                if len(out) > expected:
                    raise PngError(
                        f"PNG pixel data exceeds the {expected} bytes its header announces"
                    )
                if clock() - started > budget.max_work_s:
                    raise BudgetExceeded(
                        f"png: decoding took over the budget of {budget.max_work_s * 1000:g} ms "
                        "of work a frame; refused"
                    )
        elif kind == b"IEND":
            break
        pos = end + 4
    if len(out) != expected:
        raise PngError(f"PNG pixel data is {len(out)} bytes; its header announces {expected}")
    filters = bytes(out[:: header.stride])  # one filter byte a row (PNG spec §9)
    unfiltered = filters.lstrip(b"\x00")
    if unfiltered:
        row = len(filters) - len(unfiltered)
        raise PngError(
            f"PNG row {row} uses filter type {unfiltered[0]}; only filter 0 (None) is accepted"
        )
    del out[:: header.stride]  # C, one pass: the rows without their filter bytes
    try:
        return out.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PngError(f"PNG pixels are not UTF-8 text: {exc}") from exc


def json_values_bound(text: str) -> int:
    """An upper bound on the values a JSON text holds: each value but the first is preceded by
    ``,`` ``:`` ``[`` or ``{`` (RFC 8259 §2), and those may also appear inside strings."""
    return text.count(",") + text.count(":") + text.count("[") + text.count("{") + 1


def count_values(obj: Any, limit: int) -> int:
    """The values in a decoded frame (each array element, object key and member counts), up
    to just over ``limit``: the walk stops there, so it costs O(``limit``) at most."""
    count = 1
    stack = [obj]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            count += 2 * len(item)
            if count > limit:
                return count
            stack.extend(v for v in item.values() if isinstance(v, dict | list))
        elif isinstance(item, list | tuple):
            count += len(item)
            if count > limit:
                return count
            stack.extend(v for v in item if isinstance(v, dict | list | tuple))
    return count


def check_values(obj: Any, budget: DecodeBudget, fid: str | None = None) -> None:
    """Refuse a decoded frame of more than ``budget.max_values`` values.

    Raises:
        BudgetExceeded: it holds more.
    """
    n = count_values(obj, budget.max_values)
    if n > budget.max_values:
        raise BudgetExceeded(
            f"frame holds more than {budget.max_values} values, over the decoding budget of a "
            "frame; refused",
            id=fid,
        )


# A top-level ``"id": "…"`` near the start of a JSON frame: roslibjs and roslibpy write ``op``
# and ``id`` first. Used only to answer a frame refused before it is parsed.
_ID_RE = re.compile(r'"id"\s*:\s*"((?:[^"\\]|\\.){0,1000})"')
PEEK_CHARS = 1024


def peek_id(payload: str | bytes) -> str | None:
    """The request id of a frame not yet parsed, when it can be read cheaply from its first
    :data:`PEEK_CHARS` characters (a JSON ``"id": "…"``, or a CBOR map's ``id`` entry among
    the first ones); None otherwise. Best effort: for answering a frame refused unparsed."""
    if isinstance(payload, str):
        m = _ID_RE.search(payload, 0, PEEK_CHARS)
        if m is None:
            return None
        try:
            value = json_string(m.group(1))
        except ValueError:
            return None
        return value
    return _peek_cbor_id(payload[:PEEK_CHARS])


def json_string(body: str) -> str:
    """The value of a JSON string literal's body (without the quotes)."""
    value = json.loads(f'"{body}"')
    if not isinstance(value, str):  # pragma: no cover - a string literal decodes to str
        raise ValueError("not a string")
    return value


def _peek_cbor_id(head: bytes) -> str | None:
    if not head or head[0] >> 5 != 5:  # RFC 8949 §3.1: major type 5, a map
        return None
    info = head[0] & 0x1F
    if info < 24:
        pairs, start = info, 1
    elif info == 24 and len(head) > 1:
        pairs, start = head[1], 2
    elif info in (25, 26, 27):  # the count follows in 2, 4 or 8 bytes
        pairs, start = 8, 1 + (1 << (info - 24))
    elif info == 31:
        pairs, start = 8, 1  # indefinite length
    else:
        return None
    decoder = cbor2.CBORDecoder(io.BytesIO(head[start:]))
    for _ in range(min(pairs, 8)):
        try:
            key = decoder.decode()
            value = decoder.decode()
        except Exception:  # truncated at PEEK_CHARS, or not CBOR: no id to be had
            return None
        if key == "id":
            return value if isinstance(value, str) else None
    return None
