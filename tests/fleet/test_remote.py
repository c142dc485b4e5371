"""A remote vehicle's LTM takes part in the fleet over the bus (docs/bus.md, docs/failover.md):
its status reaches the central, the central's plans reach it as queries, and a network outage
between them is a lost drone whose post the mission frees, and a drone heard again after it.

The central is the fleet service with its central role on a Zenoh router and its REST doors
(``tests/support/bus_central.py``, ``serve``'s composition) in this process. The vehicle is, in
the first test, an LTM on the lockstep simulator joined to the router through a relay the test
cuts (a real outage: the vehicle's Zenoh session rejoins by itself), and in the second a real
``uav-console vehicle --bus-connect`` process with its own simulator on a loopback address.
"""

from __future__ import annotations

import asyncio
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from drone.bus.vehicle import VehicleBus
from drone.lockstep import LockstepRig
from drone.sim.world import load_world
from server.fleet.bus_ltm import BusLtmNode
from server.fleet.geo import Enu, origin_of
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import DroneRole, PlanKind
from server.graph import Graph
from server.settings import ROOT
from tests.support.bus_central import FLEET, BusCentral, bus_central
from tests.support.loopback import fresh_address
from tests.support.polling import until_async
from tests.support.processes import running, vehicle_key
from tests.support.relay import relay

pytestmark = pytest.mark.timeout(120)
WORLD = load_world("outdoor")
WAYPOINTS = [
    {"lat": 36.367029, "lon": 127.363305, "alt": 65.0},
    {"lat": 36.367029, "lon": 127.363639, "alt": 65.0},
]


def lockstep_ltm(name: str = "uav1") -> tuple[LockstepRig, Any, LocalTaskManager]:
    """An LTM whose drone is the lockstep simulator; the central's silence never sends it
    home here (its grace is longer than any test)."""
    from server.tasks.manager import TaskManager

    rig = LockstepRig(WORLD, n_drones=1, seed=3, camera=False, dt=0.05)
    tm = TaskManager(rig.vehicle, WORLD, rig.clock)

    def step(now: float, dt: float) -> None:
        tm.step(now)

    rig.add_stepper(step)
    ltm = LocalTaskManager(
        name,
        rig.vehicle,
        tm,
        Enu(0, 0, 0),
        origin=origin_of(WORLD),
        period_s=0.2,
        ctm_timeout_s=600.0,
    )
    rig.wait_link()
    return rig, tm, ltm


async def stepping(rig: LockstepRig, node: BusLtmNode, stop: asyncio.Event) -> None:
    """The vehicle's loop: virtual time 5× the wall's, the LTM stepped after the drone."""
    while not stop.is_set():
        rig.run(0.1)
        node.step(rig.clock.now())
        await asyncio.sleep(0.02)


def role_of(c: BusCentral, name: str) -> Callable[[], DroneRole | None]:
    return lambda: c.ctm.drones[name].role if name in c.ctm.drones else None


async def test_a_remote_ltm_on_the_bus_gets_plans_is_lost_in_an_outage_and_heard_again(
    tmp_path: Path,
) -> None:
    with bus_central(tmp_path, WORLD, ["uav1"]) as c:
        await until_async(lambda: c.role.central, 10.0, "the console holds the central role")
        cred = c.credential("uav1")
        host, port = cred.connect[0].removeprefix("tcp/").rsplit(":", 1)
        with relay(host, int(port)) as link:
            rig, tm, ltm = lockstep_ltm()
            graph = Graph()
            graph.bind_loop(asyncio.get_running_loop())
            node = BusLtmNode(graph, ltm, clock=rig.clock.now)
            bus = VehicleBus([link.endpoint], cred.user, cred.password, FLEET, "uav1")
            bus.start()
            node.join_bus(bus.session, FLEET)
            stop = asyncio.Event()
            loop_task = asyncio.create_task(stepping(rig, node, stop))
            try:
                await until_async(lambda: role_of(c, "uav1")() is DroneRole.IDLE, 20.0, "uav1 idle")
                assert c.role.info()["on_bus"] == ["uav1"]  # its status came over the bus
                plans = node.plans
                assert plans is not None
                await until_async(lambda: plans.central_alive, 10.0, "the vehicle sees a central")
                assert plans.central_name == "central"
                # a mission through the REST door
                async with httpx.AsyncClient(base_url=c.url) as http:
                    r = await http.post("/api/v1/missions", json={"waypoints": WAYPOINTS})
                    assert r.status_code == 201, r.text
                    mid = r.json()["id"]
                    bad = await http.post(
                        "/api/v1/missions", json={"markers": [1], "waypoints": WAYPOINTS}
                    )
                    assert bad.status_code == 422
                    assert (await http.get("/api/v1/missions/nope")).status_code == 404
                # the plan crossed the bus as a query, and the LTM flies it
                await until_async(lambda: ltm.plan is not None, 20.0, "the plan at the LTM")
                assert ltm.plan is not None and ltm.plan.kind is PlanKind.PATROL
                assert ltm.plan.route[0].x == pytest.approx(-15.0, abs=0.05)
                assert plans.plans >= 1
                await until_async(
                    lambda: tm.current is not None and tm.current.name == "waypoints",
                    20.0,
                    "the LTM flying the route",
                )
                assert role_of(c, "uav1")() in (DroneRole.RELIEVING, DroneRole.PATROLLING)
                # the network goes: the central loses the drone, the vehicle the central
                link.cut()
                await until_async(lambda: role_of(c, "uav1")() is DroneRole.LOST, 20.0, "uav1 lost")
                await until_async(lambda: not plans.central_alive, 10.0, "central gone")
                # the network comes back: the vehicle's session rejoins, the central hears it
                link.heal()
                await until_async(
                    lambda: role_of(c, "uav1")() not in (None, DroneRole.LOST), 30.0, "uav1 again"
                )
                assert link.accepted >= 2
                async with httpx.AsyncClient(base_url=c.url) as http:
                    fleet = (await http.get("/api/v1/fleet")).json()
                    info = (await http.get(f"/api/v1/missions/{mid}")).json()
                assert fleet["drones"][0]["name"] == "uav1"
                assert info["replacements"] == 1  # the lost drone's post was freed
            finally:
                stop.set()
                await loop_task
                node.close()
                bus.close()


async def test_a_vehicle_process_joins_the_central_over_the_bus_and_flies_its_plan(
    tmp_path: Path,
) -> None:
    """``uav-console vehicle --bus-connect … --drone sim`` with its own simulator and its own
    key: the central hears its LTM (its own station) and sends it a plan it takes."""
    key = vehicle_key(tmp_path / "console", "uav2")
    with bus_central(tmp_path, WORLD, keys={"uav2": key}) as c:
        env = {
            **os.environ,
            "UAVC_SIM_BASE_ADDR": fresh_address(),
            "UAVC_VEHICLE_KEY": key,
            "UAVC_DATA_DIR": str(tmp_path / "vehicle"),
            "PYTHONPATH": str(ROOT),
        }
        env.pop("UAVC_TOKEN", None)
        argv = [sys.executable, "-m", "server", "vehicle", "--bus-connect", c.endpoint]
        argv += ["--name", "uav2", "--drone", "sim", "--world", "outdoor"]
        log = tmp_path / "uav2.log"
        with running(argv, log, env) as proc:

            def linked() -> bool:
                assert proc.poll() is None, log.read_text()[-3000:]
                st = c.ctm.drones["uav2"].status if "uav2" in c.ctm.drones else None
                return st is not None and st.link_ok

            await until_async(linked, 90.0, "uav2's LTM status, its drone link up")
            st = c.ctm.drones["uav2"].status
            assert st is not None and st.station == Enu(1.5, 0.0, 0.0)  # its own station
            assert st.lat == pytest.approx(36.367164, abs=1e-3)
            assert c.role.info()["on_bus"] == ["uav2"]
            await until_async(lambda: c.role.central, 10.0, "the console holds the central role")
            async with httpx.AsyncClient(base_url=c.url) as http:
                r = await http.post("/api/v1/missions", json={"waypoints": WAYPOINTS})
                assert r.status_code == 201, r.text

            def applied() -> bool:
                st = c.ctm.drones["uav2"].status
                return st is not None and st.plan_id > 0

            await until_async(applied, 60.0, "uav2's LTM applying the central's plan")
            assert role_of(c, "uav2")() in (DroneRole.RELIEVING, DroneRole.PATROLLING)
            assert "refused" not in log.read_text()
