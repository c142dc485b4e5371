"""The safety port: a vehicle's own tiny HTTP door for ``emergency`` and ``land``.

A stop must never wait behind untrusted input (issue 14). The web process parses everything a
client sends; if that stalls (a 12 s PNG frame, 16 MB frames), a button click queued behind it
stalls too. So each vehicle process also listens on its own port and accepts exactly two
requests, ``POST /emergency`` and ``POST /land``, with the pilot token (``Authorization:
Bearer`` or ``?token=``), plus the CORS preflight the console's ``fetch`` needs. The request head
is capped at 4 KB and must arrive within 2 s; a body is refused; at most :data:`MAX_OPEN`
connections are open at once (more are closed unread). Nothing else is parsed, so the port
costs the flight stack little it could be slowed by.

It listens where ``serve`` does: loopback by default; with ``serve --host 0.0.0.0`` (or a LAN
address) on that too, so a phone's console reaches it, and then over TLS with ``serve``'s own
certificate when ``serve`` speaks HTTPS (an HTTPS page may not call an ``http:`` URL). Its
address as a page must call it comes from :func:`advertised_url`: the host the page was loaded
from, the port's own port and scheme. A browser ``Origin`` is accepted when it is configured,
on loopback, or the console's own page on the host the request names (:func:`page_origin`).

:func:`parse_request` is the sans-I/O part (bytes → :class:`SafetyRequest` or
:class:`SafetyRequestError`); :class:`SafetyPort` is the asyncio server around it.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import logging
import ssl
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

from server.security import parse_host
from server.vehicles.errors import VehicleError

log = logging.getLogger(__name__)

MAX_HEAD_BYTES = 4096
HEAD_TIMEOUT_S = 2.0  # also the TLS handshake's deadline
MAX_OPEN = 16  # open connections at once (a browser needs 2: preflight and POST)
ACTIONS = ("emergency", "land")
WILDCARDS = ("", "0.0.0.0", "::")


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
    host: str | None = None  # the Host header


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
    return SafetyRequest(method, action, token, headers.get("origin"), headers.get("host"))


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
        console_port: the console's port: an ``Origin`` on it naming the host the request
            names is the console's own page (:func:`page_origin`); None: not accepted so.
        tls: serve HTTPS with this context (None: plain HTTP).
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
        console_port: int | None = None,
        tls: ssl.SSLContext | None = None,
        max_open: int = MAX_OPEN,
    ) -> None:
        self.host = host
        self.port = port
        self.token = token
        self.act = act
        self.name = name
        self.origin_allowed = origin_allowed or loopback_origin
        self.console_port = console_port
        self.tls = tls
        self.max_open = max_open
        self.open = 0
        self.served = 0
        self.refused = 0
        self._server: asyncio.Server | None = None

    @property
    def url(self) -> str:
        """Where it listens (a wildcard host as bound: see :func:`advertised_url`)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'https' if self.tls else 'http'}://{host}:{self.port}"

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._serve,
            self.host or None,
            self.port,
            limit=MAX_HEAD_BYTES + 64,
            ssl=self.tls,
            ssl_handshake_timeout=HEAD_TIMEOUT_S if self.tls else None,
        )
        self.port = int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 2.0)
            self._server = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.open >= self.max_open:
            self.refused += 1
            writer.transport.abort()  # a flood: closed unread, nothing answered
            return
        self.open += 1
        try:
            await self._answer(reader, writer)
        finally:
            self.open -= 1

    async def _answer(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        origin: str | None = None
        host: str | None = None
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT_S)
                req = parse_request(head[:-4])
                origin, host = req.origin, req.host
                out = self._handle(req)
            except asyncio.LimitOverrunError:
                out = self._refuse(SafetyRequestError(431, "request head over 4 KB"), origin)
            except (TimeoutError, asyncio.IncompleteReadError):
                out = self._refuse(SafetyRequestError(408, "incomplete request"), origin)
            except SafetyRequestError as exc:
                out = self._refuse(exc, origin, host)
            writer.write(out)
            await asyncio.wait_for(writer.drain(), HEAD_TIMEOUT_S)
        except (OSError, TimeoutError, ConnectionError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    def _refuse(
        self, exc: SafetyRequestError, origin: str | None, host: str | None = None
    ) -> bytes:
        self.refused += 1
        return response(exc.status, {"error": exc.reason}, origin, self._origin_ok(origin, host))

    def _origin_ok(self, origin: str | None, host: str | None) -> bool:
        if origin is None:
            return False
        if self.origin_allowed(origin):
            return True
        return self.console_port is not None and page_origin(origin, host, self.console_port)

    def _handle(self, req: SafetyRequest) -> bytes:
        ok_origin = self._origin_ok(req.origin, req.host)
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


def page_origin(origin: str, host_header: str | None, console_port: int) -> bool:
    """Whether ``origin`` is the console's page on the host this request names: the same
    host name (an IP literal, ``localhost`` or a single-label name, which an attacker's DNS
    cannot re-point: the DNS-rebinding rule of ``Security.host_allowed``) on the console's
    port. The pilot token is still required; this only lets the page read the answer."""
    if not host_header:
        return False
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return False
    try:
        port = parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError:
        return False
    parsed = parse_host(host_header, 0)
    if parsed is None or parsed[0] != parts.hostname.lower() or port != console_port:
        return False
    name = parsed[0].strip("[]")
    return _is_ip(name) or name == "localhost" or "." not in name


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def advertised_url(bound: str | None, host_header: str | None) -> str | None:
    """The safety port's URL for a page (or script) that reached the console with this
    ``Host``: a port bound to one loopback address keeps it (the page is on this machine);
    one bound to a wildcard or a LAN address gets the host the request named, so a phone
    calls the address it already reaches. The scheme and port stay the port's own. None when
    there is no port, or no usable host for a wildcard."""
    if not bound:
        return None
    parts = urlsplit(bound)
    try:
        port = parts.port
    except ValueError:
        return None
    hostname = parts.hostname or ""
    if hostname not in WILDCARDS and _loopback(hostname):
        return bound
    parsed = parse_host(host_header, 0) if host_header else None
    if parsed is None:
        return None if hostname in WILDCARDS else bound
    name = parsed[0].strip("[]")
    host = f"[{name}]" if ":" in name else name
    return f"{parts.scheme}://{host}:{port}"


def _loopback(hostname: str) -> bool:
    if hostname == "localhost":
        return True
    try:
        return ipaddress.ip_address(hostname).is_loopback
    except ValueError:
        return False
