"""``tests/support/loopback``: fresh addresses are in this process's own block (held against
another test run), never handed out twice, come in blocks for a fleet, and pass over an address
whose simulator port something else holds (a real socket bound there)."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from drone.sim.server import SimPorts
from tests.support import loopback
from tests.support.loopback import bus_endpoint, claim_octet, fresh_address, fresh_octet

ROOT = Path(__file__).resolve().parents[1]
OTHER_RUN = """
import sys
from tests.support.loopback import fresh_address
print(fresh_address(), flush=True)
sys.stdin.read()  # holds its block until told
"""


def _octets(addr: str) -> tuple[int, int, int, int]:
    a, b, c, d = (int(x) for x in addr.split("."))
    return a, b, c, d


def test_fresh_addresses_are_in_this_processs_block_and_never_repeat() -> None:
    got = [fresh_address() for _ in range(300)]  # across a third octet
    assert len(set(got)) == len(got)
    for addr in got:
        a, b, c, d = _octets(addr)
        assert (a, b) == (127, fresh_octet()) and b in loopback.FRESH_OCTETS
        assert c < 255 and 1 <= d <= 254  # 127.B.255.x holds the claim


def test_another_test_run_gets_another_block() -> None:
    """A second process (a second pytest, an xdist worker) holds a block of its own; while it
    lives, its block cannot be claimed here even when the search starts there."""
    other = subprocess.Popen(
        [sys.executable, "-c", OTHER_RUN],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert other.stdout is not None
        theirs = _octets(other.stdout.readline().strip())[1]
        assert theirs != fresh_octet()
        octet, sock = claim_octet(theirs)
        assert sock is not None
        sock.close()
        assert octet != theirs
    finally:
        other.communicate("", timeout=30)


def test_a_block_for_a_fleet_is_consecutive_and_handed_out_once() -> None:
    first = fresh_address(3)
    after = fresh_address()
    _, b, c, d = _octets(first)
    assert d + 2 <= 254 and after not in {f"127.{b}.{c}.{d + i}" for i in range(3)}


def test_a_block_stays_in_one_third_octet_and_the_range_ends_with_an_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(loopback, "_next", [253, 253])  # far above what this run reaches
    assert fresh_address(3) == f"127.{fresh_octet()}.254.1"
    monkeypatch.setattr(loopback, "_next", [254, 253])
    with pytest.raises(RuntimeError, match="no fresh loopback address left"):
        fresh_address(3)
    with pytest.raises(ValueError, match="span"):
        fresh_address(0)


def test_an_address_whose_simulator_port_is_held_is_passed_over() -> None:
    c, d = loopback._next
    if d > 254:
        c, d = c + 1, 1
    ahead = f"127.{fresh_octet()}.{c}.{d}"  # what fresh_address would hand out next
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind((ahead, SimPorts().navdata))  # a simulator at an address picked by hand
        got = fresh_address()
    assert got != ahead
    assert loopback._in_use(ahead) is None  # released again


def test_a_bus_endpoint_is_on_a_free_port_not_the_buss_default() -> None:
    from drone.bus.session import DEFAULT_LISTEN

    endpoint = bus_endpoint()
    proto, _, rest = endpoint.partition("/")
    host, _, port = rest.rpartition(":")
    assert (proto, host) == ("tcp", "127.0.0.1") and endpoint != DEFAULT_LISTEN
    with socket.socket() as s:
        s.bind((host, int(port)))  # free
