"""Loopback addresses and ports for tests, so that two pytest-xdist workers, two test runs
and a ``make run`` on one machine never meet on a socket.

* :func:`bound_socket`, :func:`free_port`: a port the OS picks (a server whose port is settable);
  :func:`bus_endpoint`: one for a test console's bus router.
* :func:`fresh_address`: a loopback address of its own, per test or per fixture (a simulator
  whose ports are fixed, a fleet of them, a source address of its own).
* :func:`for_worker`: worker ``gwN``'s ``127.N.c.d`` for a ``127.0.c.d`` (all of 127.0.0.0/8 is
  loopback on Linux); ``make test`` runs files in two workers (``-n 2 --dist loadfile``).

``tests/test_loopback_literals.py`` finds addresses and ports picked by hand in the tests.
"""

from __future__ import annotations

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


def bus_endpoint(host: str = "127.0.0.1") -> str:
    """A bus router endpoint on a port free now (``tcp/HOST:PORT``), for a test console's
    ``UAVC_BUS_LISTEN``: left unset, a console's router takes the bus's default port 7447 (or the
    next free one), which a ``make run`` beside the tests wants."""
    return f"tcp/{host}:{free_port(host)}"


FRESH_FROM = 230
"""Third octet from which ``fresh_address`` hands out addresses (``127.N.230.1`` on): far from
the console's own simulators (``127.0.0.2`` on, ``UAVC_SIM_BASE_ADDR``'s default), so that a
``make run`` beside the tests never meets them."""

_next = [FRESH_FROM, 1]  # (third octet, last octet) of the next address to hand out


def _fixed_ports() -> list[tuple[str, int]]:
    """The sockets a simulator binds at fixed ports on its address: the AR.Drone's navdata, AT
    and video (``SimPorts``, Developer Guide §3) and the simulated PX4's TCP and UDP ports."""
    from drone.mavlink.simserver import TCP_PORT, UDP_PORT  # here: slow imports
    from drone.sim.server import SimPorts, sim_sockets

    return [*sim_sockets(SimPorts()), ("tcp", TCP_PORT), ("udp", UDP_PORT)]


def _in_use(addr: str) -> str | None:
    """Which simulator's fixed port on ``addr`` is taken now, by another test run on this
    machine ("UDP 5554 on 127.0.230.1"); None when all are free or ``addr`` cannot be probed."""
    from drone.sim.server import in_use

    try:
        return in_use(addr, _fixed_ports())
    except OSError:
        return None


SKIP_AT_MOST = 64
"""Taken blocks ``fresh_address`` passes over before it gives up (a port held on every address,
e.g. a listener on 0.0.0.0:5760, would take them all)."""


def fresh_address(span: int = 1) -> str:
    """The first of ``span`` consecutive loopback addresses that no other caller in this test
    process has had, in this worker's ``127.N.c.d`` (``c`` from ``FRESH_FROM``): for a simulator
    whose ports are fixed (the AR.Drone's 5554-5556, PX4's 5760), so that each needs an address
    of its own, and for a fleet of ``span`` simulators (``sim_endpoint`` puts the ``i``-th at
    the first address plus ``i``). Blocks where a simulator's port is already taken (by another
    test run on this machine) are skipped.

    Raises:
        ValueError: ``span`` is not in 1..254.
        RuntimeError: this process has used up its addresses, or ``SKIP_AT_MOST`` blocks in a
            row were taken.
    """
    if not 1 <= span <= 254:
        raise ValueError(f"span must be in 1..254, not {span}")
    for _ in range(SKIP_AT_MOST + 1):
        c, d = _next
        if d + span - 1 > 254:
            c, d = c + 1, 1
        if c > 255:
            raise RuntimeError("no fresh loopback address left in this test process")
        _next[:] = [c, d + span]
        block = [f"127.{worker_index()}.{c}.{d + i}" for i in range(span)]
        why = next(filter(None, map(_in_use, block)), None)
        if why is None:
            return block[0]
    raise RuntimeError(f"{SKIP_AT_MOST + 1} fresh loopback blocks in a row were taken ({why})")
