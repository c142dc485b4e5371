"""The HTTP door's guard, in front of every route (pure ASGI middleware).

Before any route, token check or body parsing runs:

- ``Host`` must parse (``127.0.0.1:abc`` → 400) and name us: an IP literal, ``localhost``, the
  served host or ``Settings.allow_hosts``; any other name may be an attacker's domain re-pointed
  at 127.0.0.1 (DNS rebinding), so it gets 421 (a WebSocket is closed before it opens).
- Request bodies are limited per route *before* they are read: a ``Content-Length`` over the
  limit gets 413 at once, and a chunked body is counted as it streams and cut off at the limit
  (a 400 MB POST without a token gets its 401 unread).
- Every response carries security headers: a Content-Security-Policy (scripts, styles and
  connections from this origin only; no framing), ``X-Frame-Options``, ``Referrer-Policy:
  no-referrer`` (the first-load ``?token=`` never leaks in a Referer) and ``nosniff``. A
  response that sets its own policy keeps it: the console page names, in ``connect-src``, the
  vehicles' safety doors it holds connections to (:func:`content_security_policy`). Served over
  TLS, every response also carries ``Strict-Transport-Security`` (:data:`HSTS`): a browser
  that has met the console over HTTPS never falls back to plain HTTP for its name.
- The console's first load with a valid ``?token=`` sets an HttpOnly, SameSite=Strict cookie,
  so the page can drop the token from its address (``history.replaceState``) and REST and the
  WebSocket keep working with the cookie.
"""

from __future__ import annotations

import json
import re
from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs

from server.http.security import TOKEN_COOKIE, Security, parse_host

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

# Longest prefix wins. Commands and missions are small JSON objects (text ≤ 2000 characters);
# speech uploads are WAV files (16 kHz mono 16-bit: 30 s ≈ 1 MB).
BODY_LIMITS: tuple[tuple[str, int], ...] = (
    ("/api/v1/speech", 16 * 1024 * 1024),
    ("/api/v1/", 64 * 1024),
    ("/", 64 * 1024),
)


def content_security_policy(connect: Iterable[str] = (), images: Iterable[str] = ()) -> str:
    """The policy, with ``connect`` (e.g. ``ws://127.0.0.1:41234``, a safety door) allowed
    besides this origin, and ``images`` (the map's tile host, ``https://tile.openstreetmap.org``)
    besides this origin's. Sources with characters a policy cannot carry are left out."""
    extra = "".join(f" {src}" for src in connect if _SOURCE_RE.match(src))
    tiles = "".join(f" {src}" for src in images if _IMAGE_SOURCE_RE.match(src))
    return (
        "default-src 'self'; script-src 'self'; style-src 'self'; "
        f"img-src 'self' data: blob:{tiles}; "
        f"media-src 'self' blob:; connect-src 'self'{extra}; object-src 'none'; "
        "base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
    )


# A host-source of CSP Level 3 §2.3.1 with scheme and port: wss://host:port (no paths).
_SOURCE_RE = re.compile(r"^(ws|wss|http|https)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):\d{1,5}$")
# A tile host: scheme, host (``*.`` for subdomains), an optional port (no paths).
_IMAGE_SOURCE_RE = re.compile(
    r"^https?://(\*\.)?([A-Za-z0-9-]+(\.[A-Za-z0-9-]+)*|\[[0-9A-Fa-f:.]+\])(:\d{1,5})?$"
)
CSP = content_security_policy()
# FastAPI's /docs and /redoc pages load Swagger UI / ReDoc from a CDN with inline scripts: they
# keep every header but a CSP that would break them (they are no place to type a token into).
DOCS_PATHS = ("/docs", "/redoc")
SECURITY_HEADERS: tuple[tuple[bytes, bytes], ...] = (
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-content-type-options", b"nosniff"),
    (b"cross-origin-opener-policy", b"same-origin"),
)
COOKIE_MAX_AGE_S = 30 * 24 * 3600
# RFC 6797 §6.1: one year, the usual max-age. No includeSubDomains: the console answers for its
# own name only. Browsers keep no HSTS for IP literals (§8.1.1), so a console reached by its
# address is unaffected; over plain HTTP the header means nothing (§7.2) and is not sent.
HSTS: tuple[bytes, bytes] = (b"strict-transport-security", b"max-age=31536000")


def body_limit(path: str) -> int:
    """The largest request body ``path`` accepts, in bytes."""
    for prefix, limit in BODY_LIMITS:
        if path.startswith(prefix):
            return limit
    return BODY_LIMITS[-1][1]


@dataclass
class HttpGuard:
    """The ASGI middleware (see the module docstring)."""

    app: ASGIApp
    security: Security

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = _headers(scope)
        https = scope.get("scheme") in ("https", "wss")
        problem = self._host_problem(headers.get("host"), https)
        if problem is not None:
            status, detail = problem
            if kind == "websocket":
                await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})
            else:
                await _reply(send, status, detail, https)
            return
        if kind == "websocket":
            await self.app(scope, receive, send)
            return
        path = scope.get("path", "/")
        limit = body_limit(path)
        declared = headers.get("content-length")
        if declared is not None:
            try:
                length = int(declared)
            except ValueError:
                await _reply(send, 400, "Content-Length is not a number", https)
                return
            if length > limit:
                await _reply(send, 413, _too_large(path, limit), https)
                return
        await self._guarded(scope, receive, send, path, limit, https)

    def _host_problem(self, host: str | None, https: bool) -> tuple[int, str] | None:
        if host is None:
            return 400, "the request has no Host header"
        parsed = parse_host(host, 443 if https else 80)
        if parsed is None:
            return 400, f"malformed Host header {host[:100]!r}"
        if not self.security.host_allowed(parsed[0]):
            return 421, (
                f"this server does not answer to the host name {parsed[0][:100]!r} "
                "(DNS rebinding guard; add it with UAVC_ALLOW_HOSTS)"
            )
        return None

    async def _guarded(
        self, scope: Scope, receive: Receive, send: Send, path: str, limit: int, https: bool
    ) -> None:
        seen = 0
        started = False
        refused = False

        async def counted_receive() -> Message:
            nonlocal seen, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    # Answer 413 now and tell the app the client left: it stops reading, and
                    # whatever it answers is dropped (FastAPI would turn an exception raised
                    # here into a 400 "error parsing the body").
                    refused = True
                    if not started:
                        await _reply(send, 413, _too_large(path, limit), https)
                    return {"type": "http.disconnect"}
            return message

        cookie = self._cookie_for(scope, https)

        async def send_with_headers(message: Message) -> None:
            nonlocal started
            if refused:
                return
            if message["type"] == "http.response.start":
                started = True
                extra = list(SECURITY_HEADERS)
                if https:
                    extra.append(HSTS)
                own = any(
                    k.lower() == b"content-security-policy" for k, _ in message.get("headers", [])
                )
                if not path.startswith(DOCS_PATHS) and not own:
                    extra.append((b"content-security-policy", CSP.encode()))
                if cookie is not None:
                    extra.append((b"set-cookie", cookie))
                message = dict(message)
                message["headers"] = [*message.get("headers", []), *extra]
            await send(message)

        await self.app(scope, counted_receive, send_with_headers)

    def _cookie_for(self, scope: Scope, https: bool) -> bytes | None:
        """A Set-Cookie for the console's first load with a valid ``?token=`` (else None)."""
        if scope.get("path") != "/" or scope.get("method") != "GET":
            return None
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        token = (query.get("token") or [""])[0]
        if not token or self.security.role_for(token) is None:
            return None
        secure = "; Secure" if https else ""
        return (
            f"{TOKEN_COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict; "
            f"Max-Age={COOKIE_MAX_AGE_S}{secure}"
        ).encode("latin-1")


def _headers(scope: Scope) -> dict[str, str]:
    return {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}


def _too_large(path: str, limit: int) -> str:
    return f"request body over the limit of {limit} bytes for {path[:100]}"


async def _reply(send: Send, status: int, detail: str, https: bool = False) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                *SECURITY_HEADERS,
                *((HSTS,) if https else ()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
