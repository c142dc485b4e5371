"""``GET /api/v1/drones/uav1/video.mjpg`` as a script reads it: multipart JPEG parts over HTTP."""

from __future__ import annotations

import re

import cv2
import httpx
import numpy as np

from .conftest import OBSERVER, Server


def _parts(server: Server, token: str, want: int) -> tuple[str, list[bytes]]:
    """Stream until ``want`` complete parts arrived; returns (content type, JPEG payloads)."""
    headers = {"Authorization": f"Bearer {token}"}
    timeout = httpx.Timeout(10.0)
    with (
        httpx.Client(base_url=server.base, timeout=timeout) as client,
        client.stream("GET", "/api/v1/drones/uav1/video.mjpg", headers=headers) as r,
    ):
        assert r.status_code == 200
        ctype = r.headers["content-type"]
        m = re.search(r"boundary=\"?([^\";]+)\"?", ctype)
        assert m, ctype
        delim = b"--" + m.group(1).encode()
        buf = b""
        parts: list[bytes] = []
        for chunk in r.iter_bytes():
            buf += chunk
            while True:
                start = buf.find(delim)
                head_end = buf.find(b"\r\n\r\n", start)
                if start < 0 or head_end < 0:
                    break
                head = buf[start + len(delim) : head_end].decode("latin-1")
                length = re.search(r"(?im)^content-length:\s*(\d+)", head)
                assert length, head
                n = int(length.group(1))
                body_start = head_end + 4
                if len(buf) < body_start + n:
                    break
                assert re.search(r"(?im)^content-type:\s*image/jpeg", head), head
                parts.append(buf[body_start : body_start + n])
                buf = buf[body_start + n :]
            if len(parts) >= want:
                return ctype, parts
    raise AssertionError(f"stream ended after {len(parts)} parts")


def test_mjpeg_stream_has_jpeg_parts(server: Server) -> None:
    ctype, parts = _parts(server, OBSERVER, 3)  # watching needs no pilot
    assert ctype.startswith("multipart/x-mixed-replace")
    for jpeg in parts:
        assert jpeg[:2] == b"\xff\xd8" and jpeg[-2:] == b"\xff\xd9"
        img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape == (360, 640, 3)
    assert len({bytes(p) for p in parts}) >= 2  # new frames, not one repeated image


def test_mjpeg_needs_a_token(server: Server) -> None:
    r = httpx.get(f"{server.base}/api/v1/drones/uav1/video.mjpg", timeout=10.0)
    assert r.status_code == 401
