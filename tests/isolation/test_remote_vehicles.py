"""``uav-console vehicle --bus-connect ENDPOINT`` processes on their own (as on other computers,
or the docker compose services) join a central ``serve --drone none`` on its bus and become
whole drones of it: REST telemetry, typed commands, ground truth, the fleet status. Each joins
with the key the console's operator made for it before ``serve`` started (``uav-console
vehicle-key NAME``), read from a file (``--key-file``)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from server.cli import main as cli_main
from tests.isolation.conftest import PILOT, Served, serve, wait_for
from tests.support.loopback import fresh_address
from tests.support.processes import running

pytestmark = pytest.mark.timeout(180)


@contextlib.contextmanager
def vehicle(srv: Served, name: str, sim_addr: str, tmp: Path) -> Iterator[subprocess.Popen[bytes]]:
    key_file = tmp / "data" / "vehicle-keys" / f"{name}.key"
    env = {**os.environ, "UAVC_TOKEN": PILOT, "UAVC_SIM_BASE_ADDR": sim_addr}
    env.pop("UAVC_VEHICLE_KEY", None)
    env["UAVC_DATA_DIR"] = str(tmp / "data")
    bus = srv.http.get("/api/v1/health").json()["bus"]["endpoints"][0]
    argv = [sys.executable, "-m", "server", "vehicle", "--bus-connect", bus, "--name", name]
    argv += ["--world", "outdoor", "--drone", "sim", "--index", "0", "--key-file", str(key_file)]
    with running(argv, tmp / f"{name}.log", env) as proc:
        yield proc


def test_remote_vehicles_join_a_central_server_as_whole_drones(tmp_path: Path) -> None:
    # The operator makes the vehicles' keys on the console's computer (its data directory).
    assert cli_main(["vehicle-key", "uav1", "uav2", "--data-dir", str(tmp_path / "data")]) == 0
    with (
        serve(tmp_path, "none", extra=("--world", "outdoor")) as srv,
        vehicle(srv, "uav1", fresh_address(), tmp_path),
        vehicle(srv, "uav2", fresh_address(), tmp_path),
    ):
        for name in ("uav1", "uav2"):
            srv.wait_vehicle(name, timeout=60)
        names = [d["name"] for d in srv.http.get("/api/v1/drones").json()]
        assert names == ["uav1", "uav2"]
        assert srv.drone("uav2")["vehicle"]["mode"] == "process"
        r = srv.http.post("/api/v1/command", json={"text": "take off", "drone": "uav2"})
        assert r.json()["accepted"], r.text
        wait_for(
            lambda: srv.http.get("/api/v1/sim/uav2/truth").json()["z"] > 0.5,
            "uav2 to take off (the simulator's ground truth through its vehicle)",
            40,
        )
        assert srv.http.get("/api/v1/sim/uav1/truth").json()["z"] < 0.05  # only uav2 flew
        fleet = srv.http.get("/api/v1/fleet").json()
        assert {d["name"] for d in fleet["drones"]} == {"uav1", "uav2"}
        r = srv.http.post("/api/v1/drones/uav2/land")
        assert r.status_code == 200
        wait_for(lambda: not srv.http.get("/api/v1/sim/uav2/truth").json()["flying"], "landing", 40)
