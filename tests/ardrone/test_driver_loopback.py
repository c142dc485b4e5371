"""ARDroneDriver ↔ SimServer over real UDP/TCP sockets on loopback addresses of their own.

The simulator runs at ``SPEED``× real time so these flights take about a second each; waits are
generous because the test machine is shared.
"""

from __future__ import annotations

import asyncio
import socket
import threading

import pytest

from drone.ardrone.driver import DECODE_S_DECAY, DECODE_S_INITIAL, ARDroneDriver
from drone.ardrone.errors import DriverNotStartedError
from drone.ardrone.navdata import CtrlState, DroneState, Navdata, encode_navdata
from drone.ardrone.protocol import DriverEvent, LinkLost, LinkRestored
from drone.sim.server import SimPorts, SimServer
from tests.support.loopback import fresh_address

SPEED = 4.0
WAIT = 10.0


def major(d: ARDroneDriver) -> CtrlState | int | None:
    nav = d.latest_navdata
    return None if nav is None or nav.demo is None else nav.demo.major


async def airborne(addr: str, **kw: object) -> tuple[SimServer, ARDroneDriver]:
    srv = SimServer(addr, speed=SPEED, **kw)  # type: ignore[arg-type]
    await srv.start()
    drv = ARDroneDriver(addr, video=False)
    await drv.start()
    await drv.wait_handshake(WAIT)
    drv.takeoff()
    await drv.wait_for(lambda d: major(d) is CtrlState.HOVERING, WAIT)
    return srv, drv


async def test_handshake_takeoff_move_land() -> None:
    addr = fresh_address()
    srv = SimServer(addr, speed=SPEED)
    async with srv, ARDroneDriver(addr, video=False) as drv:
        await drv.wait_handshake(WAIT)
        nav = drv.latest_navdata
        assert nav is not None and nav.state & DroneState.NAVDATA_DEMO and nav.demo is not None
        assert srv.client is not None and srv.client[0] == "127.0.0.1"  # answered to the sender
        drv.takeoff()
        await drv.wait_for(lambda d: major(d) is CtrlState.HOVERING, WAIT)
        assert srv.truth.z == pytest.approx(0.8, abs=0.1)
        x0 = srv.truth.x
        drv.move(0.0, -0.5, 0.0, 0.0)
        await drv.wait_for(lambda d: srv.truth.x > x0 + 0.5, WAIT)
        body = drv.latest_navdata.to_body()  # type: ignore[union-attr]
        assert body.vx_m_s > 0.2 and body.flying
        drv.land()
        await drv.wait_for(lambda d: major(d) is CtrlState.LANDED, WAIT)
        assert not srv.truth.flying and srv.truth.z == 0.0


async def test_emergency_reaches_the_drone_ahead_of_a_full_queue() -> None:
    addr = fresh_address()
    srv, drv = await airborne(addr)
    try:
        for i in range(200):  # several datagrams' worth of queued config writes
            drv.config(f"custom:key{i}", "x" * 40)
        drv.emergency()
        await drv.wait_for(lambda d: srv.truth.emergency, 2.0)
        assert srv.sim.settings.get("custom:key199") is None  # the queue had not drained
        await drv.wait_for(lambda d: srv.truth.z == 0.0, WAIT)
        await drv.wait_for(
            lambda d: bool(d.latest_navdata and d.latest_navdata.state & DroneState.EMERGENCY), WAIT
        )
        drv.reset()
        await drv.wait_for(lambda d: not srv.truth.emergency, WAIT)
    finally:
        await drv.stop()
        await srv.stop()


async def test_move_from_another_thread_is_safe() -> None:
    addr = fresh_address()
    srv, drv = await airborne(addr)
    try:
        y0 = srv.truth.y
        t = threading.Thread(target=drv.move, args=(-0.5, 0.0, 0.0, 0.0))  # left
        t.start()
        t.join()
        await drv.wait_for(lambda d: srv.truth.y > y0 + 0.3, WAIT)
    finally:
        await drv.stop()
        await srv.stop()


async def test_watchdog_client_silent_then_comwdg_clears_it() -> None:
    addr = fresh_address()
    srv, drv = await airborne(addr)
    drv.move(0.0, -0.5, 0.0, 0.0)
    await drv.wait_for(lambda d: srv.truth.vx > 0.3, WAIT)
    await drv.stop()  # the client goes silent mid-move
    await asyncio.sleep(5.0 / SPEED)  # deliberate: the client stays silent > 2 s (simulated)
    assert srv.sim.command_lost and srv.truth.flying
    assert abs(srv.truth.vx) < 0.15  # hovering on its own
    assert srv.sim.state_bits() & DroneState.COM_WATCHDOG
    async with ARDroneDriver(addr, video=False) as again:
        await again.wait_handshake(WAIT)  # already in demo mode: no new CONFIG needed
        await again.wait_for(
            lambda d: bool(
                d.latest_navdata and not d.latest_navdata.state & DroneState.COM_WATCHDOG
            ),
            WAIT,
        )
        assert not srv.sim.command_lost
    await srv.stop()


async def test_link_loss_and_recovery_by_fault_injection() -> None:
    addr = fresh_address()
    events: list[DriverEvent] = []
    srv = SimServer(addr, speed=SPEED)
    await srv.start()
    drv = ARDroneDriver(addr, video=False, on_event=events.append)
    await drv.start()
    try:
        await drv.wait_handshake(WAIT)
        srv.inject_fault("link_loss", duration_s=1.5 * SPEED)  # 1.5 s of wall time
        await drv.wait_for(lambda d: any(isinstance(e, LinkLost) for e in events), WAIT)
        assert not drv.link_up
        await drv.wait_for(lambda d: any(isinstance(e, LinkRestored) for e in events), WAIT)
        await drv.wait_for(lambda d: d.link_up, WAIT)
        drv.takeoff()
        await drv.wait_for(lambda d: srv.truth.flying, WAIT)  # commands flow again
        kinds = [type(e) for e in events if isinstance(e, LinkLost | LinkRestored)]
        assert kinds[0] is LinkLost and LinkRestored in kinds
        assert drv.events.qsize() > 0
    finally:
        await drv.stop()
        await srv.stop()


async def test_navdata_from_a_stranger_is_ignored() -> None:
    addr = fresh_address()
    other = fresh_address()
    srv = SimServer(addr, speed=SPEED)
    async with srv, ARDroneDriver(addr, video=False) as drv:
        await drv.wait_handshake(WAIT)
        port = drv._nav.get_extra_info("sockname")[1]  # type: ignore[union-attr]
        forged = encode_navdata(Navdata(DroneState.EMERGENCY, 10**9))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((other, SimPorts().navdata))  # right port, wrong host
            s.sendto(forged, ("127.0.0.1", port))
        await asyncio.sleep(0.2)  # deliberate: the forged packet has time to (not) take effect
        assert drv.latest_navdata is not None
        assert not drv.latest_navdata.state & DroneState.EMERGENCY


async def test_commands_before_start_raise_and_busy_port_raises() -> None:
    addr = fresh_address()
    with pytest.raises(DriverNotStartedError):
        ARDroneDriver(addr).takeoff()
    async with SimServer(addr, speed=SPEED):
        with pytest.raises(OSError):
            await SimServer(addr).start()


async def test_video_frames_decoded_from_tcp_5555() -> None:
    addr = fresh_address()
    pytest.importorskip("drone.ardrone.video")
    from drone.sim.world import load_world

    world = load_world("indoor")
    srv = SimServer(addr, world, speed=1.0)
    asked: list[float] = []  # what each decode asked the gate for (a vehicle's control loop)
    async with srv, ARDroneDriver(addr) as drv:
        drv.decode_gate = asked.append
        await drv.wait_handshake(WAIT)
        await drv.wait_for(lambda d: d.frames_decoded >= 5, WAIT)
        assert len(asked) >= 5 and all(0 < s < 1 for s in asked)  # asked before each decode
        assert drv.decode_s >= DECODE_S_DECAY ** len(asked) * DECODE_S_INITIAL
        frame = drv.latest_frame
        assert frame is not None and frame.shape == (360, 640, 3) and frame.dtype.name == "uint8"
        # The decoded image is the rendered view, not noise: compare with a fresh render.
        truth = srv.truth  # landed and still: the pose has not changed
        reference = srv.sim.render_frame(truth)
        assert reference is not None
        diff = abs(frame.astype(int) - reference.astype(int)).mean()
        assert diff < 12.0, diff  # H.264 at crf 23 plus per-frame sensor noise
        assert frame.std() > 10.0
        # Its PaVE timestamp is the simulator's clock when it was rendered, in ms.
        assert 0 < drv.latest_frame_ms <= srv.sim.time * 1000 + 1
        await drv.wait_for(lambda d: major(d) is not None, WAIT)
        await drv.wait_for(lambda d: d.latest_navdata.demo.num_frames >= 5, WAIT)  # type: ignore[union-attr]
        assert drv.video_errors == 0


async def test_run_sim_serves_until_cancelled_and_frees_its_ports() -> None:
    addr = fresh_address()
    from drone.sim.server import run_sim

    task = asyncio.create_task(run_sim(addr, "indoor", speed=SPEED))
    try:
        async with ARDroneDriver(addr, video=False) as drv:
            await drv.wait_handshake(WAIT)
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
    async with SimServer(addr, speed=SPEED):  # the ports were released
        pass


def test_sim_endpoints_for_a_fleet() -> None:
    from drone.sim.server import loopback_usable, sim_endpoint

    assert SimPorts() == SimPorts(navdata=5554, video=5555, at=5556)
    shifted = {SimPorts.shifted(i) for i in range(4)}
    assert len({p for s in shifted for p in (s.navdata, s.video, s.at)}) == 12  # no overlaps
    addr, ports = sim_endpoint(2)  # from UAVC_SIM_BASE_ADDR's default, 127.0.0.2: nothing bound
    if loopback_usable("127.0.0.4"):  # Linux: every 127/8 address is local
        assert (addr, ports) == ("127.0.0.4", SimPorts())
    else:  # macOS: only 127.0.0.1, with shifted ports
        assert (addr, ports) == ("127.0.0.1", SimPorts.shifted(2))
    assert not loopback_usable("203.0.113.7")  # TEST-NET-3: never local
