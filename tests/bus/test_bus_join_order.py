"""A vehicle started before its router joins the bus once the router is up: a real
``uav-console vehicle --bus-connect`` process dialling a loopback port where nothing listens
yet, then the console's router (Zenoh, in this process) opened on that port."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from drone.bus.commander import BusCommander
from drone.bus.commands import CommandReply
from drone.bus.console import ConsoleBus
from server.vehicles.keys import new_key
from tests.isolation.conftest import wait_for
from tests.support.loopback import free_port
from tests.support.processes import bus_vehicle

# serial: a vehicle process whose start a second test run on the same 2 cores slows
pytestmark = pytest.mark.serial

NAME = "uav7"


async def ask_telemetry(console: ConsoleBus) -> CommandReply:
    assert console.session is not None
    commander = BusCommander(console.session, "default", console.name)
    try:
        return await commander.command(NAME, commander.new_command(NAME, "telemetry"))
    finally:
        commander.close()


def test_a_vehicle_started_before_its_router_joins_once_the_router_is_up(tmp_path: Path) -> None:
    key = new_key()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with bus_vehicle(tmp_path, endpoint, NAME, key) as (proc, log_path):

        def vlog() -> str:
            return log_path.read_text(errors="replace")

        def waiting() -> bool:
            assert proc.poll() is None, f"the vehicle exited: {vlog()[-2000:]}"
            return "joining it when it is" in vlog()

        wait_for(waiting, "the vehicle saying the router is not up", 120)
        assert "vehicle up" in vlog() or proc.poll() is None
        console = ConsoleBus(
            tmp_path / "bus",
            "default",
            [],
            name="west",
            listen=[endpoint],
            vehicle_passwords={NAME: key},
        )
        console.start()
        try:
            wait_for(lambda: NAME in console.alive(), f"{NAME} alive on the bus", 60)
            wait_for(lambda: console.latest(NAME) is not None, f"{NAME}'s telemetry", 30)
            wait_for(lambda: f"{NAME}: on the bus at {endpoint}" in vlog(), "the join logged", 10)
            reply = asyncio.run(ask_telemetry(console))
            assert reply.accepted and reply.drone == NAME, reply
            assert "battery_pct" in reply.result
            assert proc.poll() is None
        finally:
            console.close()
