"""Third-party judges fly the MAVLink simulator over real sockets (addresses of their own):

* **MAVSDK** (PyPI ``mavsdk``, the PX4 project's client library; its C++ core ships in the
  wheel) connects over ``tcpout://ADDR:5760``, sees health ok, sets the take-off altitude,
  takes off to it, flies a ``goto_location``, returns to launch, lands and disarms, judged
  by its own telemetry; in a 3 m room its take-off to 5 m is refused with the reason;
* **pymavlink**'s ``mavutil`` does the same over ``tcp:ADDR:5760``, with two clients at once.

MAVSDK cannot sign (its Python API has no signing), so these simulators are unsigned, as
``sim --protocol mavlink --insecure`` runs on loopback; the signed path is proven with
pymavlink in ``test_mavlink_signing.py``. The simulator runs at 4× real time.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import pytest

from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.simserver import TCP_PORT, MavlinkSimServer
from drone.sim.world import load_world
from tests.support.loopback import fresh_address
from tests.support.polling import until_async

SPEED = 8.0  # simulated seconds per real second: the simulated PX4 runs its own loops


@pytest.fixture(scope="module")
def world() -> Any:
    return load_world("outdoor")


@contextlib.asynccontextmanager
async def _mavsdk(addr: str) -> AsyncIterator[tuple[Any, Any]]:
    """MAVSDK connected to the simulator at ``addr``: its (telemetry, action) plugins."""
    mavsdk = pytest.importorskip("mavsdk.asyncio")
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    config = mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
    async with mavsdk.Mavsdk(config) as m:
        await m.add_any_connection(f"tcpout://{addr}:{TCP_PORT}")
        system = await m.first_autopilot(10.0)
        assert system is not None
        tel, act = TelemetryAsync(system), ActionAsync(system)
        await until_async(tel.health_all_ok, 20.0, "MAVSDK health all ok")
        yield tel, act


async def test_mavsdk_flight_to_a_set_altitude_judged_by_mavsdk(world: Any) -> None:
    """set_takeoff_altitude(5) (MIS_TAKEOFF_ALT), take-off (param7 NaN, as MAVSDK sends it to
    PX4), goto, return to launch, land, disarm: every check on MAVSDK's own telemetry."""
    FlightMode = pytest.importorskip("mavsdk.plugins.telemetry").FlightMode

    ap = SimAutopilot(world)  # unsigned: the `--insecure` simulator, loopback only
    addr = fresh_address()
    async with (
        MavlinkSimServer(addr, ap, speed=SPEED, udp_port=None),
        _mavsdk(addr) as (tel, act),
    ):
        await act.set_takeoff_altitude(5.0)
        assert await act.get_takeoff_altitude() == pytest.approx(5.0)
        await act.arm()
        await act.takeoff()

        async def took_off() -> bool:  # at 5 m, and PX4 left TAKEOFF for HOLD
            p = await tel.position()
            return abs(p.relative_altitude_m - 5.0) < 0.15 and (
                await tel.flight_mode() == FlightMode.HOLD
            )

        await until_async(took_off, 40.0, "took_off")
        home = await tel.home()
        assert math.isclose(home.latitude_deg, 36.367164, abs_tol=1e-6)
        p = await tel.position()
        # AMSL minus home's AMSL, the height above home, and the local frame agree
        assert p.absolute_altitude_m - home.absolute_altitude_m == pytest.approx(
            p.relative_altitude_m, abs=0.05
        )
        ned = (await tel.position_velocity_ned()).position
        assert -ned.down_m == pytest.approx(p.relative_altitude_m, abs=0.1)

        wp = world.waypoints[2].geo  # (15, 15) in the map frame
        await act.goto_location(wp.lat_deg, wp.lon_deg, home.absolute_altitude_m + 8.0, 0.0)

        async def there() -> bool:
            p = await tel.position()
            return (
                abs(p.latitude_deg - wp.lat_deg) < 3e-6
                and abs(p.longitude_deg - wp.lon_deg) < 3e-6
                and abs(p.relative_altitude_m - 8.0) < 0.15
            )

        await until_async(there, 60.0, "there")
        await act.return_to_launch()

        async def landed() -> bool:
            return not await tel.in_air()

        await until_async(landed, 90.0, "landed")
        try:
            await act.disarm()  # PX4 may have disarmed itself after landing already
        except Exception as exc:
            assert "disarm" in str(exc).lower() or "denied" not in str(exc).lower()

        async def disarmed() -> bool:
            return not await tel.armed()

        await until_async(disarmed, 10.0, "disarmed")
        p = await tel.position()
        assert abs(p.latitude_deg - home.latitude_deg) < 6e-6  # back home (≈ 0.6 m)
        assert abs(p.longitude_deg - home.longitude_deg) < 6e-6
        assert p.relative_altitude_m == pytest.approx(0.0, abs=0.1)
    cmds = set(ap.commands_executed)
    assert {400, 22, 192} <= cmds  # arm/disarm, take-off, DO_REPOSITION
    assert 176 in cmds or 20 in cmds  # RTL as a mode change or as NAV_RETURN_TO_LAUNCH


async def test_mavsdk_takeoff_above_the_room_is_refused_with_the_reason() -> None:
    """A 3 m room: 5 m would end at the ceiling (MAVSDK would see 2.88 m, never 5), so MAVSDK's
    takeoff() fails, the reason is in its status text, and 2 m flies."""
    ActionError = pytest.importorskip("mavsdk.plugins.action").ActionError

    ap = SimAutopilot(load_world("indoor"))
    addr = fresh_address()
    async with (
        MavlinkSimServer(addr, ap, speed=SPEED, udp_port=None),
        _mavsdk(addr) as (tel, act),
    ):
        await act.set_takeoff_altitude(5.0)
        await act.arm()
        with pytest.raises(ActionError, match="DENIED"):
            await act.takeoff()

        async def told() -> bool:
            return "above ceiling (2.9 m)" in (await tel.status_text()).text

        await until_async(told, 10.0, "told")
        await act.set_takeoff_altitude(2.0)
        await act.takeoff()

        async def at_two_m() -> bool:
            return abs((await tel.position()).relative_altitude_m - 2.0) < 0.15

        await until_async(at_two_m, 30.0, "at_two_m")
        await act.land()
        await until_async(lambda: _not(tel.armed), 40.0, "disarmed after landing")


async def _not(get: Callable[[], Awaitable[Any]]) -> bool:
    return not await get()


def _mavutil_flight(addr: str, ap: SimAutopilot, world: Any) -> list[str]:
    from pymavlink import mavutil

    log: list[str] = []
    m = mavutil.mavlink_connection(f"tcp:{addr}:{TCP_PORT}", source_system=254)
    watcher = mavutil.mavlink_connection(f"tcp:{addr}:{TCP_PORT}", source_system=253)
    try:
        hb = m.wait_heartbeat(timeout=10)
        assert hb is not None and hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
        assert watcher.wait_heartbeat(timeout=10) is not None  # a second client at once
        m.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )

        def command(cmd: int, *params: float) -> int:
            p = list(params) + [0.0] * (7 - len(params))
            m.mav.command_long_send(m.target_system, m.target_component, cmd, 0, *p)
            ack = m.recv_match(
                type="COMMAND_ACK",
                blocking=True,
                timeout=5,
                condition=f"COMMAND_ACK.command=={cmd}",
            )
            assert ack is not None
            log.append(f"{cmd}:{ack.result}")
            return int(ack.result)

        assert command(mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
        m.motors_armed_wait()
        assert command(mavutil.mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 63.0) == 0
        while True:
            gp = m.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=5)
            if gp.relative_alt > 2900:
                break
        assert m.flightmode in ("TAKEOFF", "LOITER")  # mavutil names PX4 modes so
        wp = world.waypoints[0].geo
        m.mav.command_int_send(
            m.target_system,
            m.target_component,
            mavutil.mavlink.MAV_FRAME_GLOBAL,
            192,
            0,
            0,
            -1,
            1,
            0,
            math.nan,
            round(wp.lat_deg * 1e7),
            round(wp.lon_deg * 1e7),
            64.0,
        )
        ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack.command == 192 and ack.result == 0
        while math.dist((ap.physics.body.x, ap.physics.body.y), (-15.0, -15.0)) > 0.5:
            m.recv_match(blocking=True, timeout=1)
        assert command(mavutil.mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH) == 0
        m.motors_disarmed_wait()  # RTL lands and PX4 disarms itself
        assert watcher.recv_match(type="HEARTBEAT", blocking=True, timeout=5) is not None
    finally:
        m.close()
        watcher.close()
    return log


async def test_pymavlink_mavutil_flies_the_simulator() -> None:
    world = load_world("outdoor")
    ap = SimAutopilot(world)
    addr = fresh_address()
    async with MavlinkSimServer(addr, ap, speed=SPEED, udp_port=None):
        log = await asyncio.wait_for(asyncio.to_thread(_mavutil_flight, addr, ap, world), 120)
    assert log == ["400:0", "22:0", "20:0"]
    b = ap.physics.body
    assert math.hypot(b.x, b.y) < 0.6 and not ap.armed
