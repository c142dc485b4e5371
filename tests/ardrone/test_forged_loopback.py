"""Forged navdata on the real UDP sockets: ``ARDroneDriver`` against ``SimServer`` on loopback.

The attack of the campaign: while the drone streams (its sequence long past 1000), datagrams
from the drone's own address and port 5554 with sequence 1, 2, 3… and battery 3 % at 30 Hz.
Before: the driver took sequence 1 as a restart of the drone, believed the 3 % a second later
(the console said "Battery critical at 3 percent. Landing now.") and held the drone's own
packets back as a jump of more than 1000, waiting for a silence of the forged stream that
never came. Now the forged packets are dropped and counted, the drone's stream keeps flowing
with its real battery, and the driver reports that it doubts the navdata.

The forged datagrams leave from the simulator's own navdata socket: on the wire they are what a
spoofer on the drone's Wi-Fi sends (source address and port forged), without needing raw
sockets in the test.
"""

from __future__ import annotations

import asyncio

import pytest

from drone.ardrone.driver import ARDroneDriver
from drone.ardrone.navdata import CtrlState, Demo, DroneState, Navdata, encode_navdata
from drone.ardrone.protocol import DriverEvent, NavdataDoubt
from drone.sim.server import SimServer
from tests.support.loopback import fresh_address

SPEED = 4.0
WAIT = 10.0
UP_FOR = 50_000  # navdata packets the drone has sent already: about an hour at 15 Hz
ATTACK_HZ = 30.0
ATTACK_S = 2.5  # longer than the 1 s after which the forged battery used to be believed


def forged(seq: int, claims_restart: bool) -> bytes:
    """A forged demo packet: battery 3 %, hovering; optionally with the state bits a rebooted
    or watchdog-reset drone sets (bootstrap, COM watchdog)."""
    state = DroneState.NAVDATA_DEMO | DroneState.FLY
    if claims_restart:
        state |= DroneState.COM_WATCHDOG | DroneState.NAVDATA_BOOTSTRAP
    demo = Demo(ctrl_state=CtrlState.HOVERING << 16, battery_pct=3)
    return encode_navdata(Navdata(state=state, sequence=seq, demo=demo))


def battery(drv: ARDroneDriver) -> int:
    nav = drv.latest_navdata
    assert nav is not None and nav.demo is not None
    return nav.demo.battery_pct


@pytest.mark.parametrize("claims_restart", [False, True], ids=["plain", "claims-reboot"])
@pytest.mark.timeout(60)
async def test_forged_restart_from_the_drones_address_is_dropped_and_the_drone_is_still_heard(
    claims_restart: bool,
) -> None:
    addr = fresh_address()
    srv = SimServer(addr, speed=SPEED)
    srv.sim.navdata_sequence = UP_FOR
    events: list[DriverEvent] = []
    drv = ARDroneDriver(addr, video=False, on_event=events.append)
    async with srv, drv:
        await drv.wait_handshake(WAIT)
        drv.takeoff()
        await drv.wait_for(
            lambda d: bool(d.latest_navdata and d.latest_navdata.state & DroneState.FLY), WAIT
        )
        real_battery = battery(drv)
        assert real_battery > 90
        assert srv.client is not None and srv._nav is not None
        spoofer = srv._nav.transport  # the drone's own navdata socket (its address, port 5554)
        assert spoofer is not None

        lowest, seqs = 100, []
        for i in range(round(ATTACK_S * ATTACK_HZ)):
            spoofer.sendto(forged(i + 1, claims_restart), srv.client)
            await asyncio.sleep(1.0 / ATTACK_HZ)  # the attacker's pace
            lowest = min(lowest, battery(drv))
            assert drv.latest_navdata is not None
            seqs.append(drv.latest_navdata.sequence)

        assert lowest >= real_battery - 5, "the forged 3 % reached the driver's navdata"
        assert min(seqs) > UP_FOR, "the forged sequence was taken as a restart"
        assert seqs[-1] > seqs[0] + 20, "the drone's own packets stopped being accepted"
        assert drv.link_up
        doubts = [e for e in events if isinstance(e, NavdataDoubt)]
        assert doubts and "sequence" in doubts[0].reason
        assert drv.protocol.plausibility.dropped >= round(ATTACK_S * ATTACK_HZ) - 5
