"""The fleet inside one server process: ``FleetService`` with an in-process LTM on the graph,
missions through the REST router (httpx, ASGI), plans through the graph's service."""

from __future__ import annotations

import asyncio

import httpx
from fastapi import FastAPI

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.fleet.messages import FLEET_TOPIC, PlanKind
from server.fleet.service import FleetService
from server.graph import Graph
from server.tasks.manager import TaskManager


async def test_inprocess_fleet_on_graph() -> None:
    world = load_world("outdoor")
    rig = LockstepRig(world, n_drones=1, seed=5, camera=False, dt=0.1)
    tm = TaskManager(rig.vehicle, world, rig.clock)
    rig.add_stepper(lambda now, dt: tm.step(now))
    rig.wait_link()
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    fleet = FleetService(graph, world, clock=rig.clock.now)
    ltm = fleet.add_local("uav1", rig.vehicle, tm)
    app = FastAPI()
    app.include_router(fleet.router(), prefix="/api/v1")
    seen: list[dict] = []
    graph.subscribe(FLEET_TOPIC, seen.append)

    async def tick(seconds: float) -> None:
        for _ in range(round(seconds / 0.5)):
            rig.run(0.5)
            for n in fleet.ltm_nodes:
                n.step(rig.clock.now())
            await fleet.node.tick()
            await asyncio.sleep(0)  # let the plan-service call complete

    await tick(2.0)  # the CTM discovers the status topic, then hears the next status
    assert "uav1" in fleet.ctm.drones
    async with httpx.AsyncClient(
        transport=httpx.ASGITransport(app=app), base_url="http://test"
    ) as http:
        r = await http.post("/api/v1/missions", json={"markers": [0, 1, 2, 3], "altitude_m": 3})
        assert r.status_code == 201, r.text
        bad = await http.post("/api/v1/missions", json={"markers": [99]})
        assert bad.status_code == 422 and "99" in bad.json()["detail"]
        await tick(20.0)
        info = (await http.get(f"/api/v1/missions/{r.json()['id']}")).json()
    assert ltm.plan is not None and ltm.plan.kind is PlanKind.PATROL
    assert info["active"] == "uav1"  # took off and reached the route
    assert seen and seen[-1]["drones"][0]["role"] == "patrolling"
    assert seen[-1]["drones"][0]["latitude"] > 36.36
    assert graph.latched(FLEET_TOPIC) is not None
    await fleet.stop()
