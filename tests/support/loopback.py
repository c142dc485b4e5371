"""Loopback addresses of their own for each pytest-xdist worker.

``make test`` runs test files in two worker processes (``-n 2 --dist loadfile``): a file's
tests stay in one worker, but a fixture shared by several files (a conftest's server, the
browser suite's session server) is started once per worker, so its simulated drones need a
different address in each. Worker ``gwN`` moves ``127.0.c.d`` to ``127.N.c.d`` (all of
127.0.0.0/8 is loopback on Linux); without xdist, and in ``gw0``, the address is unchanged.
"""

from __future__ import annotations

import itertools
import os
import socket


def worker_index() -> int:
    """0 without xdist, N in worker ``gwN``."""
    name = os.environ.get("PYTEST_XDIST_WORKER", "")
    return int(name[2:]) if name.startswith("gw") and name[2:].isdigit() else 0


def for_worker(addr: str) -> str:
    """``addr`` (an IPv4 loopback address ``127.0.c.d``) in this worker's own ``127.N.c.d``."""
    a, b, c, d = addr.split(".")
    if a != "127" or b != "0":
        raise ValueError(f"{addr!r} is not a 127.0.c.d loopback address")
    return f"127.{worker_index()}.{c}.{d}"


def bound_socket(host: str = "127.0.0.1") -> socket.socket:
    """A TCP socket bound to a port the OS picks on ``host``, held open: for a server started in
    this process (``tests.support.servers``), no other process can take the port meanwhile."""
    sock = socket.socket()
    try:
        sock.bind((host, 0))
    except OSError:
        sock.close()
        raise
    return sock


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now, for a server in another process to listen on (the OS's
    pick; another process may take it before use)."""
    with bound_socket(host) as sock:
        return int(sock.getsockname()[1])


FRESH_FROM = 230
"""Third octet from which ``fresh_address`` hands out addresses; hand-picked ones stay below."""

_fresh = itertools.count()


def fresh_address() -> str:
    """A loopback address that no other caller in this test process has had, in this worker's
    ``127.N.c.d`` (``c`` from ``FRESH_FROM``): for a simulator whose ports are fixed (the
    AR.Drone's 5554-5556, PX4's 5760), so that each needs an address of its own."""
    c, d = divmod(next(_fresh), 254)
    if FRESH_FROM + c > 255:
        raise RuntimeError("no fresh loopback address left in this test process")
    return f"127.{worker_index()}.{FRESH_FROM + c}.{d + 1}"
