"""An ASGI app served by a real uvicorn in a thread of the test process, on a loopback port."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import uvicorn

from tests.support.loopback import bound_socket
from tests.support.polling import until

START_TIMEOUT_S = 20.0
"""Bound on uvicorn's start-up (import-free, so well under a second on an idle machine)."""


@dataclass(frozen=True)
class ThreadedServer:
    """A running server: where it listens and the uvicorn ``Server`` (its ``config``)."""

    host: str
    port: int
    server: uvicorn.Server

    def url(self, path: str = "", scheme: str = "http") -> str:
        """``scheme://host:port`` followed by ``path`` (``scheme="ws"`` for WebSockets)."""
        return f"{scheme}://{self.host}:{self.port}{path}"


@contextlib.contextmanager
def threaded_server(
    app: Any, host: str = "127.0.0.1", *, sock: socket.socket | None = None, **config: Any
) -> Iterator[ThreadedServer]:
    """Serve ``app`` on ``host`` at a port the OS picks, in a daemon thread, until the block ends.

    ``sock``: a socket from ``loopback.bound_socket`` when the port must be known before the app
    is built (settings that name it); it is closed with the server.

    ``config``: further ``uvicorn.Config`` arguments (``ws=``, ``http=``, ``limit_concurrency=``
    …); by default errors only are logged and WebSocket pings are off, so that a test sees only
    its own frames. The socket is bound before the thread starts (no race for the port); the
    block starts once uvicorn is serving, and leaving it shuts uvicorn down and joins the thread.
    """
    options: dict[str, Any] = {"log_level": "error", "ws_ping_interval": None}
    options.update(config)
    sock = sock or bound_socket(host)
    host = str(sock.getsockname()[0])
    port = int(sock.getsockname()[1])
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, **options))
    thread = threading.Thread(
        target=server.run, kwargs={"sockets": [sock]}, daemon=True, name=f"uvicorn:{port}"
    )
    try:
        thread.start()
        until(lambda: server.started or not thread.is_alive(), START_TIMEOUT_S, "uvicorn to start")
        if not server.started:
            raise RuntimeError(f"uvicorn on {host}:{port} stopped while starting")
        yield ThreadedServer(host, port, server)
    finally:
        server.should_exit = True
        thread.join(10)
        sock.close()
        if thread.is_alive():
            raise RuntimeError(f"uvicorn on {host}:{port} did not stop in 10 s")
