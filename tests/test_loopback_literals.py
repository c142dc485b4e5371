"""No loopback address or port picked by hand in the tests: they come from
``tests/support/loopback.py`` (``fresh_address``, ``free_port``, ``bound_socket``), so that two
xdist workers, two test runs and a ``make run`` on one machine never meet on a socket.

What counts as picked by hand (each rule a regular expression over one line of a test file):

* an address in 127.0.0.0/8 other than 127.0.0.1 (``"127.0.16.11"``, ``for_worker("127.0.44.2")``);
* a literal port after a loopback host or an interpolated one (``127.0.0.1:8000``,
  ``localhost:7447``, ``{addr}:5760``);
* a literal port given to a name ending in ``port`` (``udp_port=14580``, ``PX4_PORT = 5760``);
* a literal port after a command-line flag ending in ``port`` (``"--port", "8000"``);
* a literal port in a socket address tuple (``s.bind((addr, 5554))``, ``open_connection(host,
  5760)``, ``udp_out=("127.0.0.1", 14550)``).

127.0.0.1 itself is the loopback host every ``free_port`` and ``bound_socket`` port is on. A
literal that a test means (a documented default it checks, a string that is parsed and never
bound) is listed in ``ALLOWED`` with the reason, and the line says so in a comment.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
SUFFIXES = {".py", ".mjs", ".js"}
SKIPPED = {
    "tests/support/loopback.py",  # the allocator itself
    "tests/test_loopback_literals.py",  # this file's rules and examples
}

_PORT = r"(?!0\b)\d{1,5}\b"
RULES: dict[str, re.Pattern[str]] = {
    "address": re.compile(r"\b127\.(?!0\.0\.1\b)\d{1,3}\.\d{1,3}\.\d{1,3}\b"),
    "host:port": re.compile(
        rf"(?:\b127\.\d{{1,3}}\.\d{{1,3}}\.\d{{1,3}}|\blocalhost|\[::1\]|\{{[^{{}}\s]+\}}):{_PORT}",
        re.IGNORECASE,
    ),
    "port=": re.compile(rf"(?:\b|_)port[\"']?\s*[=:]\s*{_PORT}", re.IGNORECASE),
    "--port N": re.compile(rf"\"--[\w-]*port\",\s*\"{_PORT}\""),
    "(host, port)": re.compile(
        rf"\(\s*(?:\"[^\"]*\"|'[^']*'|\b[\w.]*(?i:addr|host|other)\w*)"
        rf"\s*,\s*(?=\d{{4,5}}\b){_PORT}\s*\)"
    ),
}

_ASGI = "no socket: the Host an ASGI transport sends, Settings' default host and port"
_HEADER = "a Host or Origin header, parsed, never bound (8000: Settings.port's default)"
_PARSED = "a string parsed or classified, never bound"
_SETTING = "a setting's value, never bound"
_BUS = "an endpoint classified, never bound (7447: the bus's DEFAULT_LISTEN port)"
_REFUSED = "serve refuses before it binds; port 1 (privileged) keeps a wrong start from serving"

ALLOWED: dict[tuple[str, str], str] = {
    ("tests/bus/test_bus_live.py", "127.0.13.1"): _PARSED,
    ("tests/bus/test_keys_payloads.py", "127.0.13.1"): _PARSED,
    ("tests/bus/test_keys_payloads.py", "127.0.13.1:30029"): _PARSED,
    ("tests/core/test_cli_settings.py", "127.0.0.7"): _PARSED,
    ("tests/core/test_cli_settings.py", "127.0.0.1:1"): _PARSED,
    ("tests/core/test_cli_settings.py", "127.0.0.1:2"): _PARSED,
    ("tests/app_client.py", "127.0.0.1:8000"): _ASGI,
    ("tests/core/test_refusals.py", "127.0.0.1:8000"): _ASGI,
    ("tests/speech/test_app.py", "127.0.0.1:8000"): _ASGI,
    ("tests/speech/test_tts.py", "127.0.0.1:8000"): _ASGI,
    ("tests/ardrone/test_driver_loopback.py", "127.0.0.2"): (
        "sim_endpoint's documented default base (UAVC_SIM_BASE_ADDR), checked, not bound"
    ),
    ("tests/ardrone/test_driver_loopback.py", "127.0.0.4"): (
        "sim_endpoint(2) from the default base, checked; only probed with port 0"
    ),
    ("tests/bus/test_bus_tls.py", "127.0.0.1:7447"): _BUS,
    ("tests/bus/test_bus_tls.py", "[::1]:7447"): _BUS,
    ("tests/bus/test_bus_tls.py", "localhost:7447"): _BUS,
    ("tests/bus/test_bus_tls.py", "[::1]:1"): _BUS,
    ("tests/core/test_hardening_api.py", "127.0.0.1:8000"): _HEADER,
    ("tests/core/test_hardening_api.py", "localhost:8000"): _HEADER,
    ("tests/core/test_hardening_api.py", "[::1]:8000"): _HEADER,
    ("tests/core/test_settings.py", "port=8123"): _SETTING,
    ("tests/core/test_settings.py", "port = 1"): _SETTING,
    ("tests/core/test_settings.py", "port=1"): _SETTING,
    ("tests/isolation/lean_probe.py", "127.0.0.1:9"): (
        "the discard port, where no console listens: bench/lean_vehicle.py runs this probe "
        "against other checkouts, so it imports nothing from tests/"
    ),
    ("tests/isolation/test_door.py", "127.0.0.1:8000"): _HEADER,
    ("tests/isolation/test_remote_units.py", "127.0.0.1:47002"): (
        "a door URL as a vehicle reports it: data, nothing listens there"
    ),
    ("tests/isolation/test_units.py", "127.0.13.2"): _PARSED,
    ("tests/isolation/test_units.py", "127.0.13.2:5001"): _PARSED,
    ("tests/isolation/test_units.py", "localhost:8000"): _HEADER,
    ("tests/isolation/test_units.py", "_port=5761"): _SETTING,
    ("tests/mavlink/test_mavlink_driver.py", "_PORT = 14550"): (
        "QGroundControl's port, where PX4 SITL pushes; bound on a fresh address"
    ),
    ("tests/rosbridge/test_security_unit.py", "127.0.0.1:8000"): _HEADER,
    ("tests/rosbridge/test_security_unit.py", "127.0.0.1:9999"): _HEADER,
    ("tests/rosbridge/test_security_unit.py", "localhost:8123"): _HEADER,
    ("tests/rosbridge/test_security_unit.py", "LOCALHOST:8123"): _HEADER,
    ("tests/speech/test_tls.py", "127.0.15.9"): _PARSED,
    ("tests/isolation/test_two_consoles.py", '"--port", "1"'): _REFUSED,
    ("tests/speech/test_tls.py", '"--port", "1"'): _REFUSED,
}
"""(file, literal as matched) -> why the test means it. Every occurrence in that file is allowed."""


def findings() -> list[tuple[str, int, str, str]]:
    """(file, line number, rule, literal) for each literal picked by hand in tests/."""
    found = []
    for path in sorted(TESTS.rglob("*")):
        rel = path.relative_to(ROOT).as_posix()
        if path.suffix not in SUFFIXES or "node_modules" in path.parts or rel in SKIPPED:
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for rule, pattern in RULES.items():
                found += [(rel, number, rule, m.group(0)) for m in pattern.finditer(line)]
    return found


def test_rules_find_what_they_are_for() -> None:
    """Each rule catches its kind of literal and leaves the allocator's ways alone."""
    caught = [
        ("address", 'SIM_ADDR = "127.0.16.11"'),
        ("address", 'for_worker("127.0.44.2")'),
        ("host:port", 'base_url="http://127.0.0.1:8000"'),
        ("host:port", '"tcp/localhost:7447"'),
        ("host:port", 'f"tcp:{addr}:5760"'),
        ("port=", "udp_port=14580,"),
        ("port=", "PX4_PORT = 5760"),
        ("--port N", '["serve", "--port", "8000"]'),
        ("(host, port)", "s.bind((other, 5554))"),
        ("(host, port)", "await asyncio.open_connection(addr, 5760)"),
        ("(host, port)", 'udp_out=("127.0.0.1", 14550),'),
    ]
    for rule, line in caught:
        assert RULES[rule].search(line), (rule, line)
    passed = [
        'f"http://127.0.0.1:{port}"',
        'f"tcp/127.0.0.1:{free_port()}"',
        "sim_base_addr=fresh_address(2)",
        "tcp_port=0, udp_port=None",
        "Gps(36.367164, 127.363472, 60.0)",
        "until(lambda: done, 10.0)",
        "np.zeros(8000, np.float32)",
        'f"tcp:{addr}:{TCP_PORT}"',
        '"--port", str(free_port())',
    ]
    for line in passed:
        assert not any(p.search(line) for p in RULES.values()), line


def test_no_loopback_literal_picked_by_hand() -> None:
    """Addresses and ports in tests come from tests/support/loopback.py (see the docstring)."""
    found = findings()
    picked = [f"{f}:{n}: {rule} {lit}" for f, n, rule, lit in found if (f, lit) not in ALLOWED]
    assert not picked, (
        "loopback addresses or ports picked by hand; take them from tests/support/loopback.py "
        "(fresh_address, free_port, bound_socket), or list a deliberate one in ALLOWED:\n"
        + "\n".join(picked)
    )


def test_every_allowed_literal_is_still_there() -> None:
    """An ALLOWED entry whose literal has gone is removed, so that the list stays true."""
    present = {(f, lit) for f, _, _, lit in findings()}
    assert not [key for key in ALLOWED if key not in present]
