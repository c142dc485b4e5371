"""A short real-time flight over real sockets: SimServer on a loopback address of its own (UDP
navdata/AT, H.264 video over TCP), the asyncio driver, the perception worker thread, the EKF and
the vehicle's 100 Hz control thread, driven by the task manager — no lockstep here."""

from __future__ import annotations

import asyncio
import contextlib
import math

import pytest

from drone.ardrone.driver import ARDroneDriver
from drone.ardrone.navdata import CtrlState
from drone.ardrone.vehicle import ARDroneVehicle
from drone.camera import CameraModel
from drone.sim.server import SimServer
from drone.sim.world import load_world
from server.tasks import TaskManager, TaskNotice
from tests.support.loopback import fresh_address
from tests.support.polling import until_async

# It asserts the control thread never stalled: a second test run sharing the 2 cores starved it
# (0.57 s without the CPU, in a two-worker run), so it runs in make test's serial run.
pytestmark = pytest.mark.serial

ADDR = fresh_address()
WAIT = 20.0


async def test_real_time_flight_to_a_marker_with_the_100_hz_control_thread() -> None:
    world = load_world("indoor")
    srv = SimServer(ADDR, world, seed=3)
    await srv.start()
    drv = ARDroneDriver(ADDR, video=True)
    vehicle = ARDroneVehicle("uav1", world, camera=CameraModel())  # localises from markers only
    tm = TaskManager(vehicle, world, vehicle.clock)
    events: list[TaskNotice] = []
    tm.on_event(events.append)

    async def step_tasks() -> None:  # what VehicleNode does at 20 Hz
        while True:
            tm.step(vehicle.clock.now())
            await asyncio.sleep(0.05)  # 20 Hz, as VehicleNode: the test runs in real time

    stepper = asyncio.create_task(step_tasks())
    try:
        await drv.start()
        await drv.wait_handshake(WAIT)
        await vehicle.start(drv)
        decisions = tm.submit([{"action": "takeoff"}, {"action": "goto", "marker": 0}])
        assert all(d.accepted for d in decisions)
        await until_async(lambda: tm.current is None and not tm.queued, 2 * WAIT, "the tasks done")
        assert events[-1].text == "Reached marker 0", events
        sp = world.marker(0).standoff(1.0)
        tr = srv.truth
        assert math.dist((tr.x, tr.y, tr.z), (sp.x, sp.y, sp.z)) < 0.2
        snap = vehicle.snapshot()
        assert snap.localised and snap.link_ok and 0 in snap.marker_ids
        stats = snap.controller
        assert stats is not None and stats.ticks > 300
        assert 95.0 < stats.rate_hz < 105.0
        assert stats.stalls == 0
        assert vehicle.ekf.stats.fixes_accepted > 20
        # Frames were stamped from their PaVE timestamps, on one drone clock.
        assert vehicle.frame_clock.frames == vehicle.frames_seen > 20
        assert vehicle.frame_clock.resets == 0
    finally:
        stepper.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await stepper
        await vehicle.stop(land=True)
        try:
            await until_async(
                lambda: srv.truth.ctrl_state is CtrlState.LANDED, WAIT, "the drone landed"
            )
        finally:
            await drv.stop()
            await srv.stop()
    assert not srv.truth.flying
