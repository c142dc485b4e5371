"""A vehicle key made while ``serve`` runs opens its bus without a restart: ``serve --fleet 0``
and ``uav-console vehicle --bus-connect`` processes (each another "machine": its own data
directory, its simulator inside); the console restarts its router with the new keys, the
vehicle already there rejoins, a new one joins, a wrong or revoked key stays out, and a
malformed key file leaves the router as it is."""

from __future__ import annotations

import json
import os
import secrets
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

from server.cli import main as cli_main
from tests.isolation.conftest import Served, serve, wait_for
from tests.support.loopback import free_port
from tests.support.processes import bus_vehicle, vehicle_key

# serial: real consoles and vehicle processes on wall-clock deadlines
pytestmark = pytest.mark.serial

START_S = 120  # serve's start on a busy 2-core machine (tests/bus/test_bus_vehicles.py's)
JOIN_S = 90  # a vehicle process's start and join, on the same machine

# Opens a Zenoh client session as vehicle-NAME with a password, in a process of its own (this
# test process forks vehicle processes and must not open Zenoh): "joined" or "refused: …".
PROBE = textwrap.dedent(
    """
    import json, sys
    from drone.bus.config import client_config
    from drone.bus.errors import BusConfigError
    from drone.bus.session import open_session
    endpoint, user, password = sys.argv[1:4]
    try:
        open_session(client_config(connect=[endpoint], user=user, password=password)).close()
    except BusConfigError as exc:
        print(json.dumps("refused: " + str(exc)[:200]))
    else:
        print(json.dumps("joined"))
    """
)


def probe(endpoint: str, name: str, key: str) -> str:
    """Whether the bus at ``endpoint`` lets ``vehicle-NAME`` in with ``key`` now."""
    out = subprocess.run(
        [sys.executable, "-c", PROBE, endpoint, f"vehicle-{name}", key],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])},
    )
    assert out.returncode == 0, out.stderr
    return str(json.loads(out.stdout.strip().splitlines()[-1]))


def joined(srv: Served, name: str) -> dict[str, Any] | None:
    """``name``'s drone as ``GET /api/v1/drones`` lists it, when its vehicle is on the bus."""
    for drone in srv.http.get("/api/v1/drones").json():
        if drone["name"] == name and (drone.get("vehicle") or {}).get("connected"):
            return dict(drone)
    return None


def alive(srv: Served) -> list[str]:
    return list(srv.http.get("/api/v1/health").json()["bus"]["alive"])


def test_a_key_made_while_serve_runs_lets_its_vehicle_join(tmp_path: Path) -> None:
    data = tmp_path / "data"
    key7 = vehicle_key(data, "uav7")  # before serve: on its bus from the start
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    extra = ("--vehicles", "process", "--fleet", "0", "--bus-listen", endpoint)
    with (
        serve(tmp_path, "sim", extra=extra, start_s=START_S) as srv,
        bus_vehicle(tmp_path, endpoint, "uav7", key7) as (_proc7, log7),
    ):
        wait_for(lambda: joined(srv, "uav7"), "uav7 on the bus", JOIN_S)
        assert probe(endpoint, "uav8", new_key()).startswith("refused")

        key8 = vehicle_key(data, "uav8")  # while serve runs
        with bus_vehicle(tmp_path, endpoint, "uav8", key8):
            wait_for(lambda: joined(srv, "uav8"), "uav8, keyed while serve ran, joined", JOIN_S)
            # the vehicle already there rejoined the restarted router by itself
            wait_for(lambda: joined(srv, "uav7"), "uav7 back on the bus", 30)
            said = wait_for(
                lambda: (t := srv.log_path.read_text()) and "vehicle keys changed" in t and t,
                "the restart said",
                30,
            )
            assert "vehicle keys changed (may join: uav8)" in said
            assert said.count("vehicle keys changed") == 1  # one key made: one restart
            assert probe(endpoint, "uav8", new_key()).startswith("refused")  # a wrong key
            assert probe(endpoint, "uav9", new_key()).startswith("refused")  # no key at all

            assert cli_main(["vehicle-key", "uav8", "--revoke", "--data-dir", str(data)]) == 0
            wait_for(lambda: "uav8" not in alive(srv), "revoked uav8 cut off the bus", 30)
            assert probe(endpoint, "uav8", key8).startswith("refused")
        wait_for(lambda: alive(srv) == ["uav7"], "uav7 alone on the bus", 30)
        assert "Traceback" not in log7.read_text(errors="replace")


def test_a_malformed_key_file_leaves_the_bus_as_it_is(tmp_path: Path) -> None:
    """A key file that holds no key is said in serve's log, and no key made beside it counts
    until it is fixed (the router keeps the keys it has); then the new key opens the bus."""
    data = tmp_path / "data"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    extra = ("--vehicles", "process", "--fleet", "0", "--bus-listen", endpoint)
    with serve(tmp_path, "sim", extra=extra, start_s=START_S) as srv:
        bad = data / "vehicle-keys" / "uav5.key"
        bad.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        bad.write_text("my pilot token, pasted\n")
        key6 = vehicle_key(data, "uav6")
        wait_for(
            lambda: f"vehicle keys: the vehicle key file {bad} holds" in srv.log_path.read_text(),
            "serve says which key file is malformed",
            30,
        )
        assert probe(endpoint, "uav6", key6).startswith("refused")  # the router left as it was
        assert "vehicle keys changed" not in srv.log_path.read_text()
        bad.unlink()
        wait_for(lambda: probe(endpoint, "uav6", key6) == "joined", "uav6 let in once fixed", 30)
        # said once the console's own session is back, which may be after a vehicle's
        wait_for(lambda: "vehicle keys changed" in srv.log_path.read_text(), "the restart said", 30)
        assert srv.log_path.read_text().count("vehicle keys changed") == 1


def new_key() -> str:
    """A well-formed vehicle key that the console never made."""
    return "uavk_" + secrets.token_urlsafe(32)
