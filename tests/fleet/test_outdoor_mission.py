"""Issue 13 §2: an outdoor patrol through ``POST /api/v1/missions`` with the dialog manager and
its ANS running on every drone — at the default 5 m it patrols; before, the ANS's global 2.8 m
ceiling replaced the patrol with "move down" and the drones hovered with no task. A mission
that would break the world's limits is refused up front with the reason."""

from __future__ import annotations

import asyncio

import httpx
import pytest
from fastapi import FastAPI

from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from drone.supervisor import supervise
from server.dialog.adapters import TaskManagerPort, VehicleAdapter
from server.dialog.manager import DialogManager
from server.fleet.messages import PlanKind
from server.fleet.service import FleetService
from server.graph import Graph
from server.settings import Settings
from server.tasks.manager import TaskManager


@pytest.mark.timeout(300)
async def test_outdoor_fleet_of_two_patrols_at_the_default_5_m() -> None:
    world = load_world("outdoor")
    rig = LockstepRig(world, n_drones=2, seed=11, camera=False, dt=0.05)
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    fleet = FleetService(graph, world, clock=rig.clock.now)
    tms, dms = [], []
    for v in rig.vehicles:
        tm = TaskManager(v, world, rig.clock)
        dm = DialogManager(
            graph,
            Settings(),
            TaskManagerPort(tm),
            VehicleAdapter(v, world),
            None,
            None,
            rig.clock.now,
            drone=v.name,
            prefix=f"/{v.name}",
        )
        rig.add_stepper(lambda now, dt, tm=tm: tm.step(now))
        rig.add_stepper(lambda now, dt, dm=dm: dm.step(now))
        sup = supervise(v, tm, world)
        sup.on_alarm(dm.hear)
        rig.add_stepper(lambda now, dt, sup=sup: sup.step(now))
        fleet.add_local(v.name, v, tm)
        tms.append(tm)
        dms.append(dm)
    assert rig.wait_link()
    app = FastAPI()
    app.include_router(fleet.router(), prefix="/api/v1")

    async def tick(seconds: float) -> None:
        for _ in range(round(seconds / 0.5)):
            rig.run(0.5)
            for n in fleet.ltm_nodes:
                n.step(rig.clock.now())
            await fleet.node.tick()
            await asyncio.sleep(0)

    await tick(2.0)
    assert set(fleet.ctm.drones) == {"uav1", "uav2"}
    async with httpx.AsyncClient(
        transport=httpx.ASGITransport(app=app), base_url="http://test"
    ) as http:
        wps = [{"lat": w.geo.lat_deg, "lon": w.geo.lon_deg} for w in world.waypoints]
        too_high = await http.post("/api/v1/missions", json={"waypoints": wps, "altitude_m": 25})
        assert too_high.status_code == 422
        detail = too_high.json()["detail"]
        assert detail == (
            "waypoint 1: a height of 25.0 m is above this flying field's ceiling of 20 m"
        ), detail
        r = await http.post("/api/v1/missions", json={"waypoints": wps})  # default altitude
        assert r.status_code == 201, r.text
        mid = r.json()["id"]
        assert mid == "m1"  # the refused one took no id
        assert [p["z"] for p in r.json()["route"]] == pytest.approx([5.0] * 4, abs=0.01)
        await tick(45.0)
        info = (await http.get(f"/api/v1/missions/{mid}")).json()
    assert info["state"] != "waiting" and info["active"] in ("uav1", "uav2"), info
    i = int(info["active"][3:]) - 1
    active = fleet.ltm_nodes[i].ltm
    assert active.plan is not None and active.plan.kind is PlanKind.PATROL
    cur = tms[i].current
    assert cur is not None and cur.name == "waypoints", tms[i].history
    assert rig.sims[i].truth.z == pytest.approx(5.0, abs=0.5)
    said = [r["text"] for dm in dms for r in dm.replies]
    assert not [t for t in said if "ceiling" in t or "Descending" in t], said
    assert not [h for tm in tms for h in tm.history if h[0].name == "move"]
    await fleet.stop()
