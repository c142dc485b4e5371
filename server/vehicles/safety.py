"""The safety port: a vehicle's own tiny HTTP door for ``emergency`` and ``land``.

A stop must never wait behind untrusted input (issue 14). The web process parses everything a
client sends; if that stalls (a 12 s PNG frame, 16 MB frames), a button click queued behind it
stalls too. So each vehicle process also listens on its own loopback port and accepts exactly
two requests, ``POST /emergency`` and ``POST /land``, with the pilot token (``Authorization:
Bearer`` or ``?token=``), plus the CORS preflight the console's ``fetch`` needs. The request head
is capped at 4 KB and must arrive within 2 s; a body is refused. Nothing else is parsed, so the
port costs the flight stack nothing it could be slowed by.

:func:`parse_request` is the sans-I/O part (bytes → :class:`SafetyRequest` or
:class:`SafetyRequestError`); :class:`SafetyPort` is the asyncio server around it.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

from server.vehicles.errors import VehicleError

log = logging.getLogger(__name__)

MAX_HEAD_BYTES = 4096
HEAD_TIMEOUT_S = 2.0
ACTIONS = ("emergency", "land")


class SafetyRequestError(VehicleError):
    """A request the safety port refuses; ``status`` is the HTTP status to answer."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


@dataclass(frozen=True)
class SafetyRequest:
    method: str  # POST or OPTIONS
    action: str  # emergency | land
    token: str | None
    origin: str | None


def parse_request(head: bytes) -> SafetyRequest:
    """Parse one request head (up to and without the blank line).

    Raises:
        SafetyRequestError: malformed (400), too large (431), a body (413), an unknown path
            (404) or method (405).
    """
    if len(head) > MAX_HEAD_BYTES:
        raise SafetyRequestError(431, "request head over 4 KB")
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError as exc:
        raise SafetyRequestError(400, "request head is not ASCII") from exc
    lines = text.split("\r\n")
    parts = lines[0].split(" ")
    if len(parts) != 3 or not parts[2].startswith("HTTP/1."):
        raise SafetyRequestError(400, "malformed request line")
    method, target = parts[0], parts[1]
    headers: dict[str, str] = {}
    for line in lines[1:]:
        if not line:
            continue
        name, sep, value = line.partition(":")
        if not sep or not name or name != name.strip():
            raise SafetyRequestError(400, "malformed header line")
        headers[name.lower()] = value.strip()
    length = headers.get("content-length", "0")
    if not length.isdigit():
        raise SafetyRequestError(400, "bad Content-Length")
    if int(length) != 0 or "transfer-encoding" in headers:
        raise SafetyRequestError(413, "the safety port takes no request body")
    url = urlsplit(target)
    action = url.path.strip("/")
    if action not in ACTIONS:
        raise SafetyRequestError(404, f"no such action {url.path!r} (emergency, land)")
    if method not in ("POST", "OPTIONS"):
        raise SafetyRequestError(405, f"{method} not allowed (POST)")
    token = None
    auth = headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        token = auth[7:].strip()
    elif url.query:
        found = parse_qs(url.query).get("token")
        token = found[0] if found else None
    return SafetyRequest(method, action, token, headers.get("origin"))


def response(
    status: int, body: dict[str, object] | None, origin: str | None, allow_origin: bool
) -> bytes:
    """One HTTP/1.1 response (connection closed after it)."""
    reasons = {200: "OK", 204: "No Content", 400: "Bad Request", 401: "Unauthorized"}
    reasons |= {403: "Forbidden", 404: "Not Found", 405: "Method Not Allowed"}
    reasons |= {408: "Request Timeout", 413: "Content Too Large"}
    reasons |= {431: "Request Header Fields Too Large"}
    payload = json.dumps(body).encode() if body is not None else b""
    lines = [f"HTTP/1.1 {status} {reasons.get(status, 'Error')}", "Connection: close"]
    lines.append(f"Content-Length: {len(payload)}")
    if payload:
        lines.append("Content-Type: application/json")
    if origin and allow_origin:
        lines += [
            f"Access-Control-Allow-Origin: {origin}",
            "Access-Control-Allow-Methods: POST",
            "Access-Control-Allow-Headers: Authorization",
            "Access-Control-Max-Age: 600",
            "Vary: Origin",
        ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + payload


class SafetyPort:
    """Serve :func:`parse_request` on ``host:port`` (0: any free port, see :attr:`port`).

    Args:
        token: the pilot token (compared in constant time).
        act: called with ``emergency`` or ``land``; returns a short detail text.
        origin_allowed: whether a browser ``Origin`` may call (CORS); None: any loopback page.
    """

    def __init__(
        self,
        host: str,
        port: int,
        token: str,
        act: Callable[[str], str],
        *,
        name: str = "uav1",
        origin_allowed: Callable[[str], bool] | None = None,
    ) -> None:
        self.host = host
        self.port = port
        self.token = token
        self.act = act
        self.name = name
        self.origin_allowed = origin_allowed or loopback_origin
        self.served = 0
        self.refused = 0
        self._server: asyncio.Server | None = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._serve, self.host, self.port, limit=MAX_HEAD_BYTES + 64
        )
        self.port = int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 2.0)
            self._server = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        origin: str | None = None
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT_S)
                req = parse_request(head[:-4])
                origin = req.origin
                out = self._handle(req)
            except asyncio.LimitOverrunError:
                out = self._refuse(SafetyRequestError(431, "request head over 4 KB"), origin)
            except (TimeoutError, asyncio.IncompleteReadError):
                out = self._refuse(SafetyRequestError(408, "incomplete request"), origin)
            except SafetyRequestError as exc:
                out = self._refuse(exc, origin)
            writer.write(out)
            await asyncio.wait_for(writer.drain(), HEAD_TIMEOUT_S)
        except (OSError, TimeoutError, ConnectionError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    def _refuse(self, exc: SafetyRequestError, origin: str | None) -> bytes:
        self.refused += 1
        ok_origin = origin is not None and self.origin_allowed(origin)
        return response(exc.status, {"error": exc.reason}, origin, ok_origin)

    def _handle(self, req: SafetyRequest) -> bytes:
        ok_origin = req.origin is not None and self.origin_allowed(req.origin)
        if req.origin is not None and not ok_origin:
            raise SafetyRequestError(403, "Origin not allowed")
        if req.method == "OPTIONS":
            return response(204, None, req.origin, ok_origin)
        if req.token is None or not hmac.compare_digest(req.token.encode(), self.token.encode()):
            raise SafetyRequestError(401, "the pilot token is required")
        detail = self.act(req.action)
        self.served += 1
        body = {"drone": self.name, "action": req.action, "accepted": True, "detail": detail}
        return response(200, body, req.origin, ok_origin)


def loopback_origin(origin: str) -> bool:
    host = urlsplit(origin).hostname or ""
    return host in ("localhost", "::1") or host.startswith("127.")
