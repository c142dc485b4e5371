"""Transport limits under uvicorn, over real sockets on loopback: a client
that never finishes its headers is cut off; connections beyond the per-IP cap are closed."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Iterator

from fastapi import FastAPI

from server.http.conn_guard import ConnectionLimits, guarded_h11
from tests.support.loopback import fresh_address
from tests.support.polling import until
from tests.support.servers import threaded_server


@contextlib.contextmanager
def serve(host: str, limits: ConnectionLimits) -> Iterator[int]:
    app = FastAPI()

    @app.get("/ping")
    def ping() -> dict[str, str]:
        return {"pong": "yes"}

    with threaded_server(app, host, http=guarded_h11(limits), lifespan="off") as served:
        yield served.port


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
    host = fresh_address()
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
    host = fresh_address()
    limits = ConnectionLimits(max_per_ip=3, header_timeout_s=30)
    with serve(host, limits) as port:
        held = [socket.create_connection((host, port), timeout=5) for _ in range(3)]
        client = held[0].getsockname()[0]  # the kernel's source address: 127.0.0.1
        until(lambda: limits.open.get(client) == 3, 10.0, "three connections counted")
        extra = socket.create_connection((host, port), timeout=5)
        assert closed_by_server(extra)
        assert limits.refused == 1
        for s in held:
            s.close()
        extra.close()
        until(lambda: not limits.open, 10.0, "the closed connections uncounted")
        assert b"200 OK" in get(host, port)
