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

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


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


# A PNG of ours has one IDAT chunk; libpng-made ones a few per megabyte. More than this many
# chunks is not an image anyone means to send (issue 14: ~900 000 one-byte IDAT chunks froze the
# loop for 12 s when they were joined one by one).
MAX_PNG_CHUNKS = 4096


def png_decode(png: bytes, limit: int = 64 * 1024 * 1024) -> str:
    """Inverse of :func:`png_encode`: the (newline-padded) text inside.

    Linear in the input: IDAT bodies are fed to one incremental inflater as they are met (no
    repeated joining), the number of chunks is capped at :data:`MAX_PNG_CHUNKS`, and inflation
    stops as soon as the pixels exceed ``limit`` bytes (a zlib bomb costs at most ``limit``).

    Raises:
        ValueError: not a PNG of this shape, truncated, too many chunks, or its pixels exceed
            ``limit`` bytes.
    """
    if not png.startswith(PNG_SIGNATURE):
        raise ValueError("not a PNG file")
    view = memoryview(png)
    pos, width, chunks = len(PNG_SIGNATURE), 0, 0
    inflater = zlib.decompressobj()
    out = bytearray()
    while pos < len(png):
        if pos + 12 > len(png):
            raise ValueError("truncated PNG chunk header")
        (length,) = struct.unpack_from(">I", png, pos)
        kind = bytes(view[pos + 4 : pos + 8])
        end = pos + 8 + length
        if end + 4 > len(png):
            raise ValueError(f"truncated PNG chunk {kind!r}")
        chunks += 1
        if chunks > MAX_PNG_CHUNKS:
            raise ValueError(f"PNG has more than {MAX_PNG_CHUNKS} chunks")
        if kind == b"IHDR":
            if length < 4:
                raise ValueError("PNG IHDR chunk is too short")
            width = struct.unpack_from(">I", png, pos + 8)[0]
        elif kind == b"IDAT":
            try:
                out += inflater.decompress(view[pos + 8 : end], limit + 1 - len(out))
            except zlib.error as exc:
                raise ValueError(f"PNG pixels are not valid zlib data: {exc}") from exc
            if len(out) > limit:
                raise ValueError(f"PNG pixels exceed {limit} bytes")
        elif kind == b"IEND":
            break
        pos = end + 4
    if width <= 0:
        raise ValueError("PNG without an IHDR chunk")
    stride = width * 3 + 1
    raw = bytes(out)
    rows = [raw[i + 1 : i + stride] for i in range(0, len(raw), stride)]
    try:
        return b"".join(rows).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"PNG pixels are not UTF-8 text: {exc}") from exc


def png_frame(text: str) -> str:
    """A ``png`` op carrying ``text``."""
    return json.dumps({"op": "png", "data": base64.b64encode(png_encode(text)).decode("ascii")})
