"""Loopback addresses for benchmarks: a TCP port free on a host now."""

from __future__ import annotations

import socket


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now (bound and released: the server started next takes it)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])
