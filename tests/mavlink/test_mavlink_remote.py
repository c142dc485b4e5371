"""``uav-console vehicle --drone tcp:ADDR:5760 --bus-connect …``: a MAVLink drone's whole stack in
its own process joins a central over the bus, as an AR.Drone's does (tests/fleet/test_remote.py).
The drone is the simulated PX4 on an address of its own, served from this test process; the
central is the fleet service on a bus router in this process (tests/support/bus_central.py)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.simserver import TCP_PORT, MavlinkSimServer
from drone.sim.world import load_world
from server.fleet.geo import Enu
from server.settings import ROOT
from tests.support.bus_central import bus_central
from tests.support.loopback import fresh_address
from tests.support.polling import until_async
from tests.support.processes import running, vehicle_key

pytestmark = pytest.mark.timeout(120)
WORLD = load_world("outdoor")


async def test_mavlink_vehicle_process_joins_the_central_over_the_bus(tmp_path: Path) -> None:
    ap = SimAutopilot(WORLD, start=(1.5, 0.0, WORLD.start.yaw_rad))
    addr = fresh_address()
    key = vehicle_key(tmp_path / "console", "uav2")
    async with MavlinkSimServer(addr, ap, udp_port=None):
        with bus_central(tmp_path, WORLD, keys={"uav2": key}) as c:
            env = {
                **os.environ,
                "UAVC_VEHICLE_KEY": key,
                "UAVC_DATA_DIR": str(tmp_path / "vehicle"),
                "PYTHONPATH": str(ROOT),
            }
            env.pop("UAVC_TOKEN", None)
            argv = [sys.executable, "-m", "server", "vehicle", "--bus-connect", c.endpoint]
            argv += ["--name", "uav2", "--drone", f"tcp:{addr}:{TCP_PORT}", "--world", "outdoor"]
            log = tmp_path / "uav2.log"
            with running(argv, log, env) as proc:

                def full() -> bool:
                    assert proc.poll() is None, log.read_text()[-3000:]
                    st = c.ctm.drones["uav2"].status if "uav2" in c.ctm.drones else None
                    return st is not None and st.link_ok and st.battery_pct > 90

                await until_async(full, 90.0, "uav2's LTM status: link up, battery full")
                st = c.ctm.drones["uav2"].status
                assert st is not None and st.station == Enu(1.5, 0.0, 0.0)
                assert st.lat == pytest.approx(36.367164, abs=1e-4)
                assert c.role.info()["on_bus"] == ["uav2"]  # its status came over the bus
                assert len(ap.links) == 1  # the vehicle process is the simulator's client
