"""Third-party check: the PyPI client ``pyardrone`` (which we did not write) flies the simulator.

pyardrone accepts navdata only from exactly the drone's host and port 5554, requires the checksum
option and dies on unknown option tags (see its ``navdata/__init__.py``) — so this also checks our
wire format. Its video mixin (OpenCV reading a UDP relay) is left out: we compose its navdata/AT
client and command helpers exactly as ``pyardrone.ARDrone`` does, minus ``VideoMixin``.
"""

from __future__ import annotations

import asyncio

import pytest

pyardrone = pytest.importorskip("pyardrone")
from pyardrone import ARDroneBase, HelperMixin  # noqa: E402
from pyardrone import at as pat  # noqa: E402

from drone.ardrone.navdata import CtrlState  # noqa: E402
from drone.sim.server import SimServer  # noqa: E402
from tests.support.loopback import fresh_address  # noqa: E402
from tests.support.polling import until_async  # noqa: E402

ADDR = fresh_address()
SPEED = 2.0  # pyardrone sends COMWDG every 0.5 s of wall time: keep that under 2 s simulated
WAIT = 10.0


class PyDrone(HelperMixin, ARDroneBase):
    """``pyardrone.ARDrone`` without its OpenCV video relay."""


def major(drone: PyDrone) -> int:
    return int(drone.navdata.demo.ctrl_state) >> 16


async def test_pyardrone_flies_the_simulator() -> None:
    async with SimServer(ADDR, speed=SPEED) as srv:
        drone = PyDrone(host=ADDR)
        try:
            assert await asyncio.to_thread(drone.navdata_ready.wait, WAIT)
            assert drone.state.navdata_bootstrap  # bootstrap until navdata_demo is set
            drone.send(pat.CONFIG("general:navdata_demo", "TRUE"))
            await until_async(lambda: hasattr(drone.navdata, "demo"), WAIT, "demo navdata")
            assert major(drone) == CtrlState.LANDED
            assert drone.navdata.demo.vbat_flying_percentage == 100

            drone.takeoff()
            await until_async(
                lambda: drone.state.fly_mask and major(drone) == CtrlState.HOVERING,
                WAIT,
                "hovering",
            )
            assert 700 <= drone.navdata.demo.altitude <= 900  # mm

            x0 = srv.truth.x
            drone.move(forward=0.5)
            await until_async(lambda: srv.truth.x > x0 + 0.5, WAIT, "moved 0.5 m forward")
            assert drone.navdata.demo.vx > 200  # mm/s forward, as the drone reports it
            drone.hover()
            await until_async(lambda: abs(srv.truth.vx) < 0.1, WAIT, "stopped")

            drone.land()
            await until_async(
                lambda: major(drone) == CtrlState.LANDED and not drone.state.fly_mask,
                WAIT,
                "landed",
            )
            assert srv.truth.z == 0.0
            assert srv.sim.rejected_at == 0  # every datagram pyardrone sent parsed
        finally:
            await asyncio.to_thread(drone.close)
