"""Outgoing frame encodings: fragments and PNG, as rosbridge_suite produces them.

- Fragments (ROSBRIDGE_PROTOCOL.md §3.3.1): the JSON text of one message split into
  ``{"op": "fragment", "id", "data", "num", "total"}`` pieces of at most ``fragment_size``
  characters; roslibjs reassembles them by ``id`` and ``num``.
- PNG (§3.3.2, rosbridge_library/internal/pngcompression.py): the JSON text's bytes laid out as
  an RGB image of width ``floor(sqrt(n/3))``, padded with newlines, base64 of the PNG file sent
  as ``{"op": "png", "data": …}``. roslibjs decodes the pixels and parses them as JSON.
"""

from __future__ import annotations

import base64
import json
import math
import struct
import zlib

from server.rosbridge.budget import PNG_SIGNATURE, DecodeBudget, png_text
from server.rosbridge.errors import BudgetExceeded

__all__ = ["PNG_SIGNATURE", "fragments", "png_decode", "png_encode", "png_frame"]


def fragments(text: str, fragment_size: int, frag_id: str) -> list[str]:
    """Split ``text`` into fragment frames of at most ``fragment_size`` characters of data."""
    size = max(1, fragment_size)
    pieces = [text[i : i + size] for i in range(0, len(text), size)] or [""]
    total = len(pieces)
    return [
        json.dumps({"op": "fragment", "id": frag_id, "data": p, "num": n, "total": total})
        for n, p in enumerate(pieces)
    ]


def png_encode(text: str) -> bytes:
    """The PNG file rosbridge_suite's ``pngcompression.encode`` would make of ``text``."""
    data = text.encode("utf-8")
    n = len(data)
    width = max(1, math.floor(math.sqrt(n / 3.0)))
    height = max(1, math.ceil((n / 3.0) / width))
    data += b"\n" * (width * height * 3 - n)
    stride = width * 3
    raw = b"".join(b"\x00" + data[r * stride : (r + 1) * stride] for r in range(height))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB
    return (
        PNG_SIGNATURE
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"IDAT", zlib.compress(raw, 6))
        + _chunk(b"IEND", b"")
    )


def _chunk(kind: bytes, body: bytes) -> bytes:
    crc = zlib.crc32(kind + body) & 0xFFFFFFFF
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)


def png_decode(png: bytes, limit: int = 64 * 1024 * 1024) -> str:
    """Inverse of :func:`png_encode`: the (newline-padded) text inside, for a PNG whose pixel
    rows unpack to at most ``limit`` bytes (linear: ``server.rosbridge.budget.png_text``).

    Raises:
        ValueError: not a PNG of this shape, truncated, too many chunks, or over ``limit``.
    """
    budget = DecodeBudget(max_png_pixels=limit, max_png_bytes=limit, max_work_s=math.inf)
    try:
        return png_text(png, budget)
    except BudgetExceeded as err:
        raise ValueError(err.msg) from err


def png_frame(text: str) -> str:
    """A ``png`` op carrying ``text``."""
    return json.dumps({"op": "png", "data": base64.b64encode(png_encode(text)).decode("ascii")})
