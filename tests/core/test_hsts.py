"""Strict-Transport-Security from the HTTP door's guard: on every answer served over TLS, never
over plain HTTP (RFC 6797 §7.2). A real uvicorn on loopback with the console's own CA and
server certificate (server/http/tls.py), and the same guard without TLS beside it."""

from __future__ import annotations

import contextlib
import ssl
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import uvicorn

from server.http.http_guard import HttpGuard
from server.http.security import Security, TokenStore
from server.http.tls import ensure_server_cert
from server.settings import Settings
from tests.support.loopback import free_port

HOST = "127.0.0.1"


async def _hello(scope: dict[str, Any], receive: Any, send: Any) -> None:
    """The smallest ASGI app: 200 with a word (the guard's headers are what is looked at)."""
    await send({"type": "http.response.start", "status": 200, "headers": []})
    await send({"type": "http.response.body", "body": b"hello"})


@contextlib.contextmanager
def _served(tmp: Path, *, tls: bool) -> Iterator[str]:
    """The guard around ``_hello`` on uvicorn in a thread; yields its base URL."""
    app = HttpGuard(_hello, Security(Settings(data_dir=tmp), TokenStore(tmp)))  # type: ignore[arg-type]
    port = free_port(HOST)
    files = ensure_server_cert(tmp / "tls", HOST) if tls else None
    config = uvicorn.Config(
        app,
        host=HOST,
        port=port,
        log_level="error",
        lifespan="off",
        ssl_certfile=str(files.cert) if files else None,
        ssl_keyfile=str(files.key) if files else None,
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "uvicorn did not start"
        time.sleep(0.01)
    try:
        yield f"{'https' if tls else 'http'}://{HOST}:{port}"
    finally:
        server.should_exit = True
        thread.join(10)


def test_hsts_on_every_https_answer_and_never_on_http(tmp_path: Path) -> None:
    with _served(tmp_path, tls=True) as base:
        ca = ssl.create_default_context(cafile=str(tmp_path / "tls" / "ca.pem"))
        with httpx.Client(base_url=base, verify=ca, timeout=10) as client:
            ok = client.get("/")
            refused = client.get("/", headers={"Host": "evil.example"})  # the guard's own 421
            too_big = client.post("/api/v1/command", content=b"x" * (65 * 1024))  # its 413
    assert ok.status_code == 200 and ok.text == "hello"
    assert (refused.status_code, too_big.status_code) == (421, 413)
    for answer in (ok, refused, too_big):
        assert answer.headers["strict-transport-security"] == "max-age=31536000"
    with _served(tmp_path, tls=False) as base:
        plain = httpx.get(f"{base}/", timeout=10)
        refused = httpx.get(f"{base}/", headers={"Host": "evil.example"}, timeout=10)
    assert plain.status_code == 200 and refused.status_code == 421
    assert "strict-transport-security" not in plain.headers
    assert "strict-transport-security" not in refused.headers
    assert plain.headers["x-frame-options"] == "DENY"  # the other headers as ever
