"""Loopback addresses and ports for tests, so that two pytest-xdist workers, two test runs
and a ``make run`` on one machine never meet on a socket.

* :func:`bound_socket`, :func:`free_port`: a port the OS picks (a server whose port is settable);
  :func:`bus_endpoint`: one for a test console's bus router.
* :func:`fresh_address`: a loopback address of its own, per test or per fixture (a simulator
  whose ports are fixed, a fleet of them, a source address of its own), in a ``127.B`` block
  that the test process holds while it runs.
* :func:`for_worker`: worker ``gwN``'s ``127.N.c.d`` for a ``127.0.c.d`` (all of 127.0.0.0/8 is
  loopback on Linux); ``make test`` runs files in two workers (``-n 2 --dist loadfile``).

``tests/test_loopback_literals.py`` finds addresses and ports picked by hand in the tests.
"""

from __future__ import annotations

import errno
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


FRESH_OCTETS = range(128, 256)
"""Second octets ``fresh_address`` hands out from, one per test process (``127.B.c.d``): above
the worker blocks of ``for_worker`` (``127.N``) and the console's own simulators (``127.0.0.2``
on, ``UAVC_SIM_BASE_ADDR``'s default), so that a ``make run`` beside the tests never meets
them."""

CLAIM_PORT = 65535
"""The port of the socket by which a test process holds its second octet (on ``127.B.255.254``,
an address ``fresh_address`` never hands out): bound without ``SO_REUSEADDR``, so a second
process cannot bind it while the first lives, and the kernel lets go when the process ends."""

_claim: list[tuple[int, socket.socket | None]] = []  # (second octet, the socket holding it)
_next = [0, 1]  # (third octet, last octet) of the next address to hand out


def claim_octet(start: int) -> tuple[int, socket.socket | None]:
    """The first second octet from ``start`` (cycling through ``FRESH_OCTETS``) that no other
    live process holds, and the socket that holds it for this one; ``start`` and None where
    only 127.0.0.1 is local (macOS: the simulators fall back to it with shifted ports).

    Raises:
        RuntimeError: every octet is held.
    """
    count = len(FRESH_OCTETS)
    for i in range(count):
        octet = FRESH_OCTETS[(start - FRESH_OCTETS.start + i) % count]
        sock = socket.socket()
        try:
            sock.bind((f"127.{octet}.255.254", CLAIM_PORT))
        except OSError as exc:
            sock.close()
            if exc.errno == errno.EADDRNOTAVAIL:
                return start, None
            continue
        return octet, sock
    raise RuntimeError(f"every loopback block 127.{FRESH_OCTETS.start}-255.x.x is held")


def fresh_octet() -> int:
    """This test process's second octet for fresh addresses, claimed on first use (the search
    starts from the process id, so that concurrent runs rarely even try the same one)."""
    if not _claim:
        _claim.append(claim_octet(FRESH_OCTETS.start + os.getpid() % len(FRESH_OCTETS)))
    return _claim[0][0]


def _fixed_ports() -> list[tuple[str, int]]:
    """The sockets a simulator binds at fixed ports on its address: the AR.Drone's navdata, AT
    and video (``SimPorts``, Developer Guide §3) and the simulated PX4's TCP and UDP ports."""
    from drone.mavlink.simserver import TCP_PORT, UDP_PORT  # here: slow imports
    from drone.sim.server import SimPorts, sim_sockets

    return [*sim_sockets(SimPorts()), ("tcp", TCP_PORT), ("udp", UDP_PORT)]


def _in_use(addr: str) -> str | None:
    """Which simulator's fixed port on ``addr`` is taken now ("UDP 5554 on 127.128.0.1"); None
    when all are free or ``addr`` cannot be probed."""
    from drone.sim.server import in_use

    try:
        return in_use(addr, _fixed_ports())
    except OSError:
        return None


SKIP_AT_MOST = 64
"""Taken blocks ``fresh_address`` passes over before it gives up (a port held on every address,
e.g. a listener on 0.0.0.0:5760, would take them all)."""


def fresh_address(span: int = 1) -> str:
    """The first of ``span`` consecutive loopback addresses that no other caller has had: in
    ``127.B.c.d``, ``B`` this test process's own (:func:`fresh_octet`; an xdist worker is a
    process of its own, and so is a second test run on the machine), for a simulator whose
    ports are fixed (the AR.Drone's 5554-5556, PX4's 5760), so that each needs an address of
    its own, and for a fleet of ``span`` simulators (``sim_endpoint`` puts the ``i``-th at the
    first address plus ``i``). A block where a simulator's port is taken anyway (by a process
    that picked its address by hand) is passed over.

    Raises:
        ValueError: ``span`` is not in 1..254.
        RuntimeError: this process has used up its addresses, or ``SKIP_AT_MOST`` blocks in a
            row were taken.
    """
    if not 1 <= span <= 254:
        raise ValueError(f"span must be in 1..254, not {span}")
    octet = fresh_octet()
    for _ in range(SKIP_AT_MOST + 1):
        c, d = _next
        if d + span - 1 > 254:
            c, d = c + 1, 1
        if c > 254:  # 127.B.255.x: the claim's
            raise RuntimeError("no fresh loopback address left in this test process")
        _next[:] = [c, d + span]
        block = [f"127.{octet}.{c}.{d + i}" for i in range(span)]
        why = next(filter(None, map(_in_use, block)), None)
        if why is None:
            return block[0]
    raise RuntimeError(f"{SKIP_AT_MOST + 1} fresh loopback blocks in a row were taken ({why})")
