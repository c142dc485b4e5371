"""The whole server as a third party sees it: ``python -m server serve`` in a subprocess.

One server for the directory (start-up costs a few seconds): the real simulated AR.Drone on
a loopback address of its own (UAVC_SIM_BASE_ADDR) in real time (UAVC_SIM_SPEED
1: the EKF and the 100 Hz PID run on the wall clock, so a faster simulator would be a drone that
reacts faster than the controller was tuned for), the real driver, vehicle, task manager, dialog
manager and rosbridge. Clients are real: roslibpy (PyPI), the ``websockets`` library, and httpx
over TCP. Tests that fly leave the drone landed.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
import roslibpy

from tests.support.loopback import bus_endpoint, free_port, fresh_address
from tests.support.polling import until, wait_for

ROOT = Path(__file__).resolve().parents[2]
PILOT = "e2e-pilot-token"
OBSERVER = "e2e-observer-token"
SIM_ADDR = fresh_address()
SIM_SPEED = "1"
TIMEOUT = 10.0


@dataclass
class Server:
    """A running ``uav-console serve`` on loopback, and a pilot-token REST client to it."""

    port: int
    http: httpx.Client
    proc: subprocess.Popen[bytes]
    log_path: Path

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def ws_url(self, token: str | None = PILOT) -> str:
        query = f"?token={token}" if token else ""
        return f"ws://127.0.0.1:{self.port}/rosbridge{query}"

    def truth(self) -> dict[str, Any]:
        r = self.http.get("/api/v1/sim/uav1/truth")
        r.raise_for_status()
        return dict(r.json())

    def drone(self) -> dict[str, Any]:
        r = self.http.get("/api/v1/drones/uav1")
        r.raise_for_status()
        return dict(r.json())

    def wait_truth(
        self, pred: Callable[[dict[str, Any]], bool], timeout: float = 15.0, what: str = ""
    ) -> dict[str, Any]:
        """Poll the simulator's ground truth until ``pred`` holds (fails the test otherwise)."""
        return wait_for(self.truth, pred, timeout, what or "truth")

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-4000:]

    def ensure_landed(self) -> None:
        """Bring the drone to the ground (and out of emergency) before or after a flight."""
        t = self.truth()
        if t["emergency"]:
            self.http.post("/api/v1/drones/uav1/reset")
        if t["flying"] or t["z"] > 0.05:
            self.http.post("/api/v1/drones/uav1/land")
        self.wait_truth(lambda t: not t["flying"] and t["z"] < 0.05, 20.0, "landed")


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    data = tmp_path_factory.mktemp("e2e-data")
    port = free_port()
    env = dict(os.environ, UAVC_SIM_BASE_ADDR=SIM_ADDR, UAVC_SIM_SPEED=SIM_SPEED)
    # Console behaviour, not isolation: flight stacks inline unless UAVC_VEHICLES says otherwise
    # (serve defaults to process mode; tests/isolation covers it).
    env.setdefault("UAVC_VEHICLES", "inline")
    env.setdefault("UAVC_BUS_LISTEN", bus_endpoint())  # a bus router off 7447
    log_path = data / "server.log"
    cmd = [
        sys.executable,
        "-m",
        "server",
        "serve",
        "--port",
        str(port),
        "--token",
        PILOT,
        "--observer-token",
        OBSERVER,
        "--data-dir",
        str(data),
    ]
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    http = httpx.Client(
        base_url=f"http://127.0.0.1:{port}",
        headers={"Authorization": f"Bearer {PILOT}"},
        timeout=10.0,
    )
    srv = Server(port, http, proc, log_path)
    try:

        def healthy() -> bool:
            if proc.poll() is not None:
                raise RuntimeError(f"server exited with {proc.returncode}:\n{srv.log()}")
            health = http.get("/api/v1/health")
            return health.status_code == 200 and bool(health.json()["drones"].get("uav1"))

        try:
            until(healthy, 40.0, "the server healthy", ignore=(httpx.TransportError,))
        except AssertionError:
            raise RuntimeError(f"server did not become healthy:\n{srv.log()}") from None
        yield srv
    finally:
        http.close()
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


@pytest.fixture
def landed(server: Server) -> Iterator[Server]:
    """The server with the drone on the ground before and after the test."""
    server.ensure_landed()
    yield server
    server.ensure_landed()


@pytest.fixture
def ros(server: Server) -> Iterator[roslibpy.Ros]:
    """A roslibpy client connected with the pilot token."""
    client = roslibpy.Ros(server.ws_url(PILOT))
    client.run(timeout=TIMEOUT)
    yield client
    client.close()
