"""``uav-console vehicle --drone tcp:ADDR:5760``: a MAVLink drone's stack in its own process joins a
central server over the rosbridge WebSocket, as an AR.Drone's does (tests/fleet/test_remote.py).
The vehicle is the simulated PX4 on an address of its own, served from this test process."""

from __future__ import annotations

import asyncio
import contextlib
import os
import subprocess
import sys
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI

from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.simserver import TCP_PORT, MavlinkSimServer
from drone.sim.world import load_world
from server.fleet.ctm import CentralTaskManager
from server.fleet.geo import Enu, origin_of
from server.fleet.node import CtmNode
from server.graph import Graph
from server.http.security import Security, TokenStore
from server.rosbridge.context import BridgeContext
from server.rosbridge.endpoint import make_router
from server.settings import ROOT, Settings
from tests.support.loopback import bound_socket, fresh_address
from tests.support.polling import until_async
from tests.support.servers import threaded_server

pytestmark = pytest.mark.timeout(90)
WORLD = load_world("outdoor")


@contextlib.contextmanager
def _central(tmp: Path) -> Iterator[tuple[str, CentralTaskManager, str]]:
    host = fresh_address()
    sock = bound_socket(host)
    port = int(sock.getsockname()[1])
    settings = Settings(host=host, port=port, data_dir=tmp, world="outdoor")
    graph = Graph()
    tokens = TokenStore(tmp)
    ctx = BridgeContext(graph=graph, security=Security(settings, tokens), settings=settings)
    ctm = CentralTaskManager(origin=origin_of(WORLD), world=WORLD, lost_after_s=1.5)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        graph.bind_loop(asyncio.get_running_loop())
        node = CtmNode(graph, ctm, period_s=0.1, publish_period_s=0.2)
        await node.start()
        yield
        await node.stop()

    app = FastAPI(lifespan=lifespan)
    app.include_router(make_router(ctx))
    with threaded_server(app, sock=sock) as served:
        yield served.url("/rosbridge", scheme="ws"), ctm, tokens.pilot_token


async def test_mavlink_vehicle_process_joins_the_central(tmp_path: Path) -> None:
    ap = SimAutopilot(WORLD, start=(1.5, 0.0, WORLD.start.yaw_rad))
    addr = fresh_address()
    async with MavlinkSimServer(addr, ap, udp_port=None):
        with _central(tmp_path) as (ws, ctm, token):
            cmd = [
                sys.executable,
                "-m",
                "server",
                "vehicle",
                "--central",
                ws,
                "--name",
                "uav2",
                "--drone",
                f"tcp:{addr}:{TCP_PORT}",
                "--world",
                "outdoor",
                f"--token={token}",
            ]
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            proc = subprocess.Popen(
                cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
            )
            try:
                await until_async(
                    lambda: "uav2" in ctm.drones or proc.poll() is not None,
                    40.0,
                    "uav2 to join (or its process to end)",
                )
                assert proc.poll() is None, proc.stdout.read().decode()[-2000:]  # type: ignore[union-attr]
                await until_async(
                    lambda: (
                        (st := ctm.drones["uav2"].status) is not None
                        and st.link_ok
                        and st.battery_pct > 90
                    ),
                    20.0,
                    "uav2's status: link up, battery full",
                )
                st = ctm.drones["uav2"].status
                assert st is not None and st.station == Enu(1.5, 0.0, 0.0)
                assert st.lat == pytest.approx(36.367164, abs=1e-4)
                assert len(ap.links) == 1  # the vehicle process is the simulator's client
            finally:
                proc.terminate()
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
                if proc.stdout is not None:
                    proc.stdout.close()
