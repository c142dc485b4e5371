"""A remote LTM joins the central server over a real rosbridge WebSocket on loopback.

The server is a minimal FastAPI app with the rosbridge endpoint (server/rosbridge) and the
fleet router, run by uvicorn in a thread; the CTM runs on its loop through ``CtmNode``. The
vehicle side is ``VehicleClient`` around an LTM whose drone is the lockstep simulator (advanced
in virtual time as the client steps), and, in the last test, a real ``uav-console vehicle``
process with its own simulator on a loopback address.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import subprocess
import sys
import threading
import time
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
from fastapi import FastAPI

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.fleet.client import VehicleClient
from server.fleet.ctm import CentralTaskManager
from server.fleet.geo import Enu, origin_of
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import DroneRole, PlanKind
from server.fleet.node import CtmNode
from server.fleet.router import make_fleet_router
from server.graph import Graph
from server.http.security import Security, TokenStore
from server.rosbridge.context import BridgeContext
from server.rosbridge.endpoint import make_router
from server.settings import ROOT, Settings
from tests.support.loopback import free_port, fresh_address

pytestmark = pytest.mark.timeout(60)
WORLD = load_world("outdoor")


@dataclass
class Central:
    port: int
    graph: Graph
    ctm: CentralTaskManager
    node: CtmNode
    token: str
    loop: asyncio.AbstractEventLoop

    @property
    def ws(self) -> str:
        return f"ws://127.0.0.1:{self.port}/rosbridge"

    def call(self, fn: Any, *args: Any) -> Any:
        async def run() -> Any:
            return fn(*args)

        return asyncio.run_coroutine_threadsafe(run(), self.loop).result(10)


@contextlib.contextmanager
def central_server(tmp: Path) -> Iterator[Central]:
    port = free_port()
    settings = Settings(port=port, data_dir=tmp, world="outdoor")
    graph = Graph()
    tokens = TokenStore(tmp)
    ctx = BridgeContext(graph=graph, security=Security(settings, tokens), settings=settings)
    ctm = CentralTaskManager(origin=origin_of(WORLD), world=WORLD, lost_after_s=1.5)
    box: dict[str, Any] = {}

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        graph.bind_loop(asyncio.get_running_loop())
        node = CtmNode(graph, ctm, period_s=0.1, publish_period_s=0.2)
        await node.start()
        box["node"], box["loop"] = node, asyncio.get_running_loop()
        yield
        await node.stop()

    app = FastAPI(lifespan=lifespan)
    app.include_router(make_router(ctx))
    app.include_router(
        make_fleet_router(ctm, on_change=lambda: box["node"].poke()), prefix="/api/v1"
    )
    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error", ws_ping_interval=None)
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "server did not start"
        time.sleep(0.01)
    try:
        yield Central(port, graph, ctm, box["node"], tokens.pilot_token, box["loop"])
    finally:
        server.should_exit = True
        thread.join(10)


async def until(pred: Any, timeout_s: float = 15.0) -> None:
    """Wait for something another thread or process does (polling real I/O, not timing)."""
    end = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < end, "condition not reached in time"
        await asyncio.sleep(0.02)


def lockstep_ltm(name: str = "uav1") -> tuple[LockstepRig, Any, LocalTaskManager]:
    from server.tasks.manager import TaskManager

    rig = LockstepRig(WORLD, n_drones=1, seed=3, camera=False, dt=0.05)
    tm = TaskManager(rig.vehicle, WORLD, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    ltm = LocalTaskManager(
        name, rig.vehicle, tm, Enu(0, 0, 0), origin=origin_of(WORLD), period_s=0.2
    )
    rig.wait_link()
    return rig, tm, ltm


async def test_remote_ltm_joins_gets_plan_and_reconnects(tmp_path: Path) -> None:
    with central_server(tmp_path) as c:
        rig, tm, ltm = lockstep_ltm()
        client = VehicleClient(
            c.ws,
            ltm,
            token=c.token,
            clock=rig.clock.now,
            period_s=0.02,
            step_tasks=lambda now: rig.run(0.1),  # virtual time runs 5× faster than the wall
            backoff_s=(0.05, 0.2),
        )
        stop = asyncio.Event()
        task = asyncio.create_task(client.run(stop))
        try:
            await until(lambda: "uav1" in c.ctm.drones)
            assert c.ctm.drones["uav1"].role is DroneRole.IDLE
            assert c.graph.service_type("/uav1/fleet/flight_plan") == "uav_console/FlightPlan"
            # a mission through the REST door
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{c.port}") as http:
                wps = [
                    {"lat": 36.367029, "lon": 127.363305, "alt": 65.0},
                    {"lat": 36.367029, "lon": 127.363639, "alt": 65.0},
                ]
                r = await http.post("/api/v1/missions", json={"waypoints": wps})
                assert r.status_code == 201, r.text
                mid = r.json()["id"]
                bad = await http.post("/api/v1/missions", json={"markers": [1], "waypoints": wps})
                assert bad.status_code == 422
                assert (await http.get("/api/v1/missions/nope")).status_code == 404
            # the plan crossed the WebSocket and the LTM flies it
            await until(lambda: ltm.plan is not None)
            assert ltm.plan is not None and ltm.plan.kind is PlanKind.PATROL
            assert ltm.plan.route[0].x == pytest.approx(-15.0, abs=0.05)
            await until(lambda: tm.current is not None and tm.current.name == "waypoints")
            assert c.ctm.drones["uav1"].role in (DroneRole.RELIEVING, DroneRole.PATROLLING)
            assert client.core.heartbeats > 0
            # the link drops: the CTM loses it, the client reconnects, the CTM hears it again
            await client.drop(hold_s=2.5)
            await until(lambda: c.ctm.drones["uav1"].role is DroneRole.LOST)
            await until(lambda: client.connects >= 2)
            await until(lambda: c.ctm.drones["uav1"].role is not DroneRole.LOST)
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{c.port}") as http:
                fleet = (await http.get("/api/v1/fleet")).json()
                info = (await http.get(f"/api/v1/missions/{mid}")).json()
            assert fleet["drones"][0]["name"] == "uav1"
            assert info["replacements"] == 1  # the lost drone's post was freed
        finally:
            stop.set()
            await task


async def test_vehicle_process_joins(tmp_path: Path) -> None:
    """``python -m server vehicle`` with its own simulator joins over the WebSocket."""
    with central_server(tmp_path) as c:
        env = dict(os.environ, UAVC_SIM_BASE_ADDR=fresh_address(), PYTHONPATH=str(ROOT))
        cmd = [
            sys.executable,
            "-m",
            "server",
            "vehicle",
            "--central",
            c.ws,
            "--name",
            "uav2",
            "--drone",
            "sim",
            "--world",
            "outdoor",
            f"--token={c.token}",
        ]
        proc = subprocess.Popen(
            cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
        )
        try:
            await until(lambda: "uav2" in c.ctm.drones or proc.poll() is not None, 40.0)
            assert proc.poll() is None, proc.stdout.read().decode()[-2000:]  # type: ignore[union-attr]
            await until(lambda: (st := c.ctm.drones["uav2"].status) is not None and st.link_ok)
            st = c.ctm.drones["uav2"].status
            assert st is not None and st.station == Enu(1.5, 0.0, 0.0)  # its own station
            assert st.lat == pytest.approx(36.367164, abs=1e-3)
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            if proc.stdout is not None:
                proc.stdout.close()
