"""``serve`` opens the bus and its vehicle processes join it: a third-party Zenoh script, given
only the client configuration ``serve`` wrote, watches a drone's telemetry and liveliness."""

from __future__ import annotations

import itertools
import json
import os
import socket
import statistics
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from server.cli import main as cli_main
from tests.isolation.conftest import HOST, ROOT, serve, wait_for
from tests.support.loopback import free_port, fresh_address

# serial: real consoles and vehicle processes on wall-clock deadlines (a command 2 s late
# is refused), which a second test run on the same 2 cores made them miss
pytestmark = pytest.mark.serial

START_S = 120  # serve's start on a busy 2-core machine (tests/bus/test_bus_vehicles.py's)

SCRIPT = textwrap.dedent(
    """
    import json, sys, threading, zenoh
    conf = zenoh.Config.from_file(sys.argv[1])
    samples, done = [], threading.Event()
    def on_sample(sample):
        samples.append(json.loads(sample.payload.to_string()))
        if len(samples) >= 12:
            done.set()
    with zenoh.open(conf) as session:
        alive = [str(r.ok.key_expr) for r in session.liveliness().get("uavc/default/*/alive")]
        sub = session.declare_subscriber("uavc/default/uav1/telemetry", on_sample)
        done.wait(30)
        print(json.dumps({"alive": alive, "samples": samples}))
    """
)


def test_a_third_party_script_watches_a_served_drone(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {"UAVC_SIM_BASE_ADDR": fresh_address()}
    extra = ("--vehicles", "process", "--bus-listen", endpoint)
    with serve(tmp_path, "sim", extra=extra, env=env, start_s=START_S) as srv:
        srv.wait_vehicle()
        health = wait_for(
            lambda: (h := srv.http.get("/api/v1/health").json())["bus"]["alive"] and h,
            "uav1 alive on the bus",
        )
        assert health["bus"]["endpoints"] == [endpoint]
        client_file = Path(health["bus"]["client_config"])
        assert client_file == tmp_path / "data" / "bus" / "client.json5"
        assert client_file.stat().st_mode & 0o077 == 0
        assert str(client_file) in srv.log()  # serve says where it is
        out = subprocess.run(
            [sys.executable, "-c", SCRIPT, str(client_file)],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    # the drone, and the console holding the central role (docs/failover.md)
    assert sorted(result["alive"]) == ["uavc/default/central/alive", "uavc/default/uav1/alive"]
    samples = result["samples"]
    assert len(samples) >= 12
    for field in ("stamp", "x", "y", "z", "yaw_deg", "battery_pct", "state"):
        assert field in samples[-1], field
    assert samples[-1]["drone"] == "uav1" and samples[-1]["state"] == "LANDED"
    periods = [b["stamp"] - a["stamp"] for a, b in itertools.pairwise(samples)]
    assert statistics.median(periods) <= 0.2  # at least 5 Hz, as the vehicle stamps them


def test_a_vehicle_from_elsewhere_joins_the_bus_with_its_key(tmp_path: Path) -> None:
    """``uav-console vehicle --bus-connect ENDPOINT --name NAME --key-file …`` on another
    computer: with a key the operator made before ``serve --fleet 0`` started, it is on the
    bus as ``vehicle-NAME``."""
    assert cli_main(["vehicle-key", "uav7", "--data-dir", str(tmp_path / "data")]) == 0
    key_file = tmp_path / "data" / "vehicle-keys" / "uav7.key"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    extra = ("--vehicles", "process", "--fleet", "0", "--bus-listen", endpoint)
    with serve(tmp_path, "sim", extra=extra, start_s=START_S) as srv:
        assert srv.http.get("/api/v1/drones").json() == []  # --fleet 0: none of its own
        env = {**os.environ, "UAVC_SIM_BASE_ADDR": fresh_address()}
        env.pop("UAVC_VEHICLE_KEY", None)
        env["UAVC_DATA_DIR"] = str(tmp_path / "vehicle-data")
        argv = [sys.executable, "-m", "server", "vehicle", "--name", "uav7", "--drone", "sim"]
        argv += ["--index", "0", "--key-file", str(key_file), "--bus-connect", endpoint]
        with open(tmp_path / "uav7.log", "wb") as log:
            proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=log, stderr=log)
        try:
            wait_for(
                lambda: srv.http.get("/api/v1/health").json()["bus"]["alive"] == ["uav7"],
                "uav7 alive on the bus",
                60,
            )
        finally:
            proc.terminate()
            proc.wait(20)


def test_serve_refuses_to_start_when_its_bus_cannot(tmp_path: Path) -> None:
    """The vehicle processes join the console over its bus: a router that cannot listen where
    it is told stops ``serve`` with one line saying why and what to change, before any drone
    starts."""
    with socket.create_server(("127.0.0.1", 0)) as held:  # a port taken by someone else
        endpoint = f"tcp/127.0.0.1:{held.getsockname()[1]}"
        env = {**os.environ, "UAVC_DATA_DIR": str(tmp_path / "data")}
        argv = [sys.executable, "-m", "server", "serve", "--host", HOST, "--port"]
        argv += [str(free_port(HOST)), "--drone", "sim", "--sim-addr", fresh_address()]
        argv += ["--vehicles", "process", "--bus-listen", endpoint]
        out = subprocess.run(
            argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=START_S
        )
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("uav-console serve: error: the bus did not start: "), lines
    assert "--bus-listen ENDPOINT" in lines[0] and "--vehicles inline" in lines[0]
