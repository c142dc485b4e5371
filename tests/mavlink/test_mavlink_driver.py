"""The asyncio driver over real sockets: TCP, UDP both ways, MAVLink 2 signing, and the
``uav-console sim --protocol mavlink`` process with mavutil over TCP and UDP."""

from __future__ import annotations

import asyncio
import contextlib
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from drone.mavlink.driver import MavlinkDriver
from drone.mavlink.errors import ConnectionStringError
from drone.mavlink.gcs.events import CommandResult
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.simserver import TCP_PORT, UDP_PORT, MavlinkSimServer
from drone.sim.world import load_world
from tests.support.loopback import fresh_address
from tests.support.polling import until, until_async

ROOT = Path(__file__).resolve().parents[2]
KEY = bytes(range(100, 132))
GCS_PORT = 14550  # QGroundControl's port, where PX4 SITL pushes (on an address of its own)


@pytest.fixture(scope="module")
def world() -> Any:
    return load_world("outdoor")


async def test_driver_over_tcp_arms_and_takes_off(world: Any) -> None:
    events: list[Any] = []
    addr = fresh_address()
    async with MavlinkSimServer(addr, SimAutopilot(world), speed=4.0) as sim:
        d = MavlinkDriver(f"tcp:{addr}:{TCP_PORT}", on_event=events.append)
        await d.start()
        try:
            await until_async(
                lambda: d.protocol.telemetry.home is not None,
                10.0,
                "d.protocol.telemetry.home is not None",
            )
            d.protocol.arm_and_takeoff(3.0)
            d.flush()
            await until_async(
                lambda: d.protocol.telemetry.rel_alt_m > 2.8,
                15.0,
                "d.protocol.telemetry.rel_alt_m > 2.8",
            )
            flight = ("COMPONENT_ARM_DISARM", "NAV_TAKEOFF")
            done = [
                e.command
                for e in events
                if isinstance(e, CommandResult) and e.ok and e.command in flight
            ]
            assert done == list(flight)
            assert sim.autopilot.commands_executed.count(400) == 1
        finally:
            await d.stop()


async def test_driver_udpin_hears_a_vehicle_that_pushes(world: Any) -> None:
    # PX4 SITL pushes to the ground station's 14550 (QGroundControl's port); here the driver
    # listens there on an address of its own.
    gcs = fresh_address()
    d = MavlinkDriver(f"udpin:{gcs}:{GCS_PORT}")
    await d.start()
    try:
        sim = MavlinkSimServer(
            fresh_address(),
            SimAutopilot(world),
            tcp_port=None,
            udp_port=UDP_PORT,
            udp_out=(gcs, GCS_PORT),
            speed=4.0,
        )
        async with sim:
            await until_async(lambda: d.protocol.connected, 10.0, "d.protocol.connected")
            # replies go back to where the datagrams came from: commands work
            d.protocol.intent("hold")
            d.flush()
            await until_async(
                lambda: d.protocol.pending_commands() == 0,
                10.0,
                "d.protocol.pending_commands() == 0",
            )
    finally:
        await d.stop()


async def test_signed_link_and_a_wrong_key(world: Any) -> None:
    addr = fresh_address()
    async with MavlinkSimServer(
        addr, SimAutopilot(world, signing_key=KEY), udp_port=None, speed=4.0
    ) as sim:
        good = MavlinkDriver(f"tcp:{addr}:{TCP_PORT}", GcsProtocol(signing_key=KEY))
        bad = MavlinkDriver(f"tcp:{addr}:{TCP_PORT}", GcsProtocol(signing_key=bytes(32)))
        plain = MavlinkDriver(f"tcp:{addr}:{TCP_PORT}")
        for d in (good, bad, plain):
            await d.start()
        try:
            await until_async(
                lambda: good.protocol.telemetry.home is not None,
                10.0,
                "good.protocol.telemetry.home is not None",
            )
            good.protocol.command(400, 1.0)
            good.flush()
            await until_async(
                lambda: good.protocol.telemetry.armed, 5.0, "good.protocol.telemetry.armed"
            )
            bad.protocol.command(400, 0.0)
            plain.protocol.command(400, 0.0)
            bad.flush()
            plain.flush()
            await asyncio.sleep(1.0)  # a second in which the wrong key must not connect
            assert not bad.protocol.connected
            assert bad.protocol.codec.rejected["bad_signature"] > 0
            # MAVLink 2 lets a system without the key read signed frames (mavlink.io "Message
            # Signing"), so an unsigned console watches, but nothing it sends is obeyed:
            assert plain.protocol.connected
            assert sim.autopilot.rejected()["bad_signature"] > 0  # their commands: refused
            assert sim.autopilot.armed  # the unsigned disarm did nothing
        finally:
            for d in (good, bad, plain):
                await d.stop()


async def test_serial_radio_link_over_a_pty(world: Any) -> None:
    """``--drone /dev/pts/N,57600``: a pseudo-terminal stands in for the radio; the simulated
    autopilot sits on its other end (what a SiK radio pair carries, byte for byte)."""
    import os

    master, slave = os.openpty()
    os.set_blocking(master, False)
    ap = SimAutopilot(world)
    d = MavlinkDriver(f"{os.ttyname(slave)},57600")
    await d.start()
    try:
        end = time.monotonic() + 10
        while time.monotonic() < end and not d.protocol.telemetry.home:
            with contextlib.suppress(BlockingIOError):  # nothing written by the driver yet
                ap.receive("radio", os.read(master, 4096))
            for _ in range(5):
                ap.step(0.01)
            out = ap.drain("radio")
            if out:
                os.write(master, out)
            await asyncio.sleep(0.01)  # the driver's loop reads the pty between two steps
        assert d.protocol.connected and d.protocol.telemetry.autopilot == "PX4"
        assert d.protocol.telemetry.home is not None
    finally:
        await d.stop()
        os.close(master)
        os.close(slave)


async def test_missing_serial_device_is_a_clear_error() -> None:
    d = MavlinkDriver("/dev/ttyUSB99,57600")
    with pytest.raises(ConnectionStringError, match="cannot open /dev/ttyUSB99,57600"):
        await d.start()


def test_cli_sim_protocol_mavlink_with_mavutil_over_tcp_and_udp(tmp_path: Path) -> None:
    """The transports (signing: tests/mavlink/test_mavlink_signing.py)."""
    from pymavlink import mavutil

    addr = fresh_address()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "server",
            "sim",
            "--protocol",
            "mavlink",
            "--addr",
            addr,
            "--world",
            "outdoor",
            "--insecure",
            "--data-dir",
            str(tmp_path),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        tcp = until(
            lambda: mavutil.mavlink_connection(f"tcp:{addr}:{TCP_PORT}", autoreconnect=False),
            30.0,
            "the simulator process listening",
            period=0.2,
            ignore=(OSError,),
        )
        hb = tcp.wait_heartbeat(timeout=10)
        assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
        assert hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR
        udp = mavutil.mavlink_connection(f"udpout:{addr}:{UDP_PORT}")
        udp.mav.heartbeat_send(6, 8, 0, 0, 0)  # a datagram makes us a peer
        assert udp.wait_heartbeat(timeout=10) is not None
        gps = udp.recv_match(type="GPS_RAW_INT", blocking=True, timeout=5)
        assert gps.fix_type == 3 and math.isclose(gps.lat / 1e7, 36.367164, abs_tol=1e-5)
        tcp.close()
        udp.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()


def test_drone_flag_and_signing_key_errors_are_clear() -> None:
    from server.settings import SettingsError
    from server.vehicles.mavlink_stack import drone_kind, is_mavlink, signing_key

    assert drone_kind("sim,sim-mavlink", 0) == "sim"
    assert drone_kind("sim,sim-mavlink", 5) == "sim-mavlink"  # the last kind repeats
    assert is_mavlink("sim-mavlink") and is_mavlink("udpin:0.0.0.0:14550")
    assert not is_mavlink("192.168.1.1") and not is_mavlink("sim")
    with pytest.raises(SettingsError, match="tcp:HOST:PORT"):
        is_mavlink("tcp:10.0.0.5")
    assert signing_key(None) is None and signing_key("ab" * 32) == bytes([0xAB]) * 32
    for bad in ("abc", "zz" * 32, "ab" * 31):
        with pytest.raises(SettingsError, match="64 hex digits"):
            signing_key(bad)
