"""Transport limits under uvicorn (issue 14), over real sockets on 127.0.14.3/4: a client
that never finishes its headers is cut off; connections beyond the per-IP cap are closed."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator

import uvicorn
from fastapi import FastAPI

from server.conn_guard import ConnectionLimits, guarded_h11


@contextlib.contextmanager
def serve(host: str, limits: ConnectionLimits) -> Iterator[int]:
    app = FastAPI()

    @app.get("/ping")
    def ping() -> dict[str, str]:
        return {"pong": "yes"}

    with socket.socket() as s:
        s.bind((host, 0))
        port = int(s.getsockname()[1])
    config = uvicorn.Config(
        app, host=host, port=port, log_level="error", http=guarded_h11(limits), lifespan="off"
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "server did not start"
        time.sleep(0.01)
    try:
        yield port
    finally:
        server.should_exit = True
        thread.join(10)


def closed_by_server(sock: socket.socket, wait_s: float = 10.0) -> bool:
    """True once the server closed ``sock`` (EOF or reset), False if still open after wait_s."""
    sock.settimeout(wait_s)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


def get(host: str, port: int) -> bytes:
    with socket.create_connection((host, port), timeout=5) as s:
        s.sendall(f"GET /ping HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
        return s.recv(4096)


def test_slow_headers_are_cut_off() -> None:
    host = "127.0.14.3"
    limits = ConnectionLimits(header_timeout_s=0.3)
    with serve(host, limits) as port:
        slow = socket.create_connection((host, port), timeout=5)
        slow.sendall(b"GET /ping HTTP/1.1\r\nHost: x\r\nX-Slow: ")  # never finished
        assert closed_by_server(slow)
        slow.close()
        assert limits.timed_out == 1
        assert b"200 OK" in get(host, port)  # a normal request is served (and not cut off)
        assert limits.timed_out == 1


def test_connections_per_ip_are_capped() -> None:
    host = "127.0.14.4"
    limits = ConnectionLimits(max_per_ip=3, header_timeout_s=30)
    with serve(host, limits) as port:
        held = [socket.create_connection((host, port), timeout=5) for _ in range(3)]
        for _ in range(100):
            if limits.open.get(host) == 3:
                break
            time.sleep(0.02)
        extra = socket.create_connection((host, port), timeout=5)
        assert closed_by_server(extra)
        assert limits.refused == 1
        for s in held:
            s.close()
        extra.close()
        for _ in range(100):
            if not limits.open:
                break
            time.sleep(0.02)
        assert b"200 OK" in get(host, port)
