"""``tests/support/loopback``: fresh addresses are this worker's, never handed out twice, come in
blocks for a fleet, and pass over an address whose simulator port another run holds (a real
socket bound there)."""

from __future__ import annotations

import socket

import pytest

from drone.sim.server import SimPorts
from tests.support import loopback
from tests.support.loopback import bus_endpoint, fresh_address, worker_index


def _octets(addr: str) -> tuple[int, int, int, int]:
    a, b, c, d = (int(x) for x in addr.split("."))
    return a, b, c, d


def test_fresh_addresses_are_this_workers_and_never_repeat() -> None:
    got = [fresh_address() for _ in range(300)]  # across a third octet
    assert len(set(got)) == len(got)
    for addr in got:
        a, b, c, d = _octets(addr)
        assert (a, b) == (127, worker_index()) and c >= loopback.FRESH_FROM and 1 <= d <= 254


def test_a_block_for_a_fleet_is_consecutive_and_handed_out_once() -> None:
    first = fresh_address(3)
    after = fresh_address()
    _, _, c, d = _octets(first)
    block = {f"127.{worker_index()}.{c}.{d + i}" for i in range(3)}
    assert d + 2 <= 254 and after not in block


def test_a_block_stays_in_one_third_octet_and_the_range_ends_with_an_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(loopback, "_next", [254, 253])  # far above what this run reaches
    assert fresh_address(3) == f"127.{worker_index()}.255.1"
    monkeypatch.setattr(loopback, "_next", [255, 253])
    with pytest.raises(RuntimeError, match="no fresh loopback address left"):
        fresh_address(3)
    with pytest.raises(ValueError, match="span"):
        fresh_address(0)


def test_an_address_whose_simulator_port_is_held_is_passed_over() -> None:
    c, d = loopback._next
    if d > 254:
        c, d = c + 1, 1
    ahead = f"127.{worker_index()}.{c}.{d}"  # what fresh_address would hand out next
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind((ahead, SimPorts().navdata))  # another run's simulator, say
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
