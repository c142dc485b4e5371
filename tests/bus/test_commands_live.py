"""Commands over a real bus on loopback: a console's embedded router, a vehicle answering its
``cmd`` queryable, and consoles, pilots and observers querying it."""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from drone.bus import keys
from drone.bus.commanded import CommandedVehicle, CommandRefused, ConsolePresence
from drone.bus.commander import BusCommander
from drone.bus.commands import Command, decode_reply
from drone.bus.config import OBSERVER_USER, PILOT_USER, client_config
from drone.bus.console import ConsoleBus
from drone.bus.errors import NoReply
from drone.bus.lease import VehicleLease
from drone.bus.payloads import Status
from drone.bus.session import open_session
from tests.support.loopback import free_port
from tests.support.polling import wait_for


@pytest.fixture(scope="module")
def console(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ConsoleBus]:
    """One console router for the module: each test brings its own vehicle session, commanders
    and lease, and closes them, so what one test declares is gone before the next."""
    bus = ConsoleBus(
        tmp_path_factory.mktemp("commands-live") / "bus",
        "default",
        ["uav1", "uav2"],
        name="west",
        listen=[f"tcp/127.0.0.1:{free_port()}"],
    )
    bus.start()
    yield bus
    bus.close()


def session_as(bus: ConsoleBus, user: str) -> zenoh.Session:
    assert bus.credentials is not None
    return open_session(
        client_config(connect=bus.listen, user=user, password=bus.credentials.password(user))
    )


class FakeDrone:
    """What a vehicle does with a command: records it; takeoff waits until released."""

    def __init__(self) -> None:
        self.done: list[str] = []
        self.release = asyncio.Event()

    async def handle(self, cmd: Command) -> dict[str, Any]:
        if cmd.op == "direct" and cmd.action == "reset":
            raise CommandRefused("the drone is flying: no reset")
        if cmd.op == "direct" and cmd.action == "takeoff" and cmd.args.get("wait"):
            await self.release.wait()
        self.done.append(cmd.action or cmd.op)
        return {"detail": f"{cmd.action or cmd.op} sent"}


async def vehicle(
    bus: ConsoleBus, name: str, drone: FakeDrone
) -> tuple[zenoh.Session, CommandedVehicle]:
    cred = bus.vehicle_credential(name)
    session = open_session(
        client_config(connect=list(cred.connect), user=cred.user, password=cred.password)
    )
    cv = CommandedVehicle(
        session, "default", name, drone.handle, VehicleLease(), asyncio.get_running_loop()
    )
    cv.start()
    return session, cv


async def until_answered(commander: BusCommander, drone: str) -> None:
    """The queryable is declared on the router once a read is answered."""
    for _ in range(100):
        try:
            await commander.command(drone, commander.new_command(drone, "lease"), 1.0)
            return
        except NoReply:
            await asyncio.sleep(0.05)
    raise AssertionError(f"{drone} never answered")


def test_commands_are_answered_accepted_or_refused_with_the_reason(console: ConsoleBus) -> None:
    async def main() -> None:
        assert console.session is not None
        drone = FakeDrone()
        session, cv = await vehicle(console, "uav1", drone)
        a = BusCommander(console.session, "default", "west")
        try:
            await until_answered(a, "uav1")
            ok = await a.command("uav1", a.new_command("uav1", "direct", {"action": "takeoff"}))
            assert ok.accepted and ok.result == {"detail": "takeoff sent"} and ok.drone == "uav1"
            no = await a.command("uav1", a.new_command("uav1", "direct", {"action": "reset"}))
            assert not no.accepted and no.reason == "the drone is flying: no reset"
            assert drone.done == ["takeoff"]
            with pytest.raises(NoReply, match="uav9 did not answer"):
                await a.command("uav9", a.new_command("uav9", "telemetry"), 2.0)
        finally:
            a.close()
            cv.close()
            session.close()

    asyncio.run(main())


def test_the_lease_is_the_vehicles_one_across_consoles(console: ConsoleBus) -> None:
    async def main() -> None:
        assert console.session is not None
        drone = FakeDrone()
        session, cv = await vehicle(console, "uav1", drone)
        pilot = session_as(console, PILOT_USER)
        west = BusCommander(console.session, "default", "west")
        east = BusCommander(pilot, "default", "east")
        try:
            await until_answered(east, "uav1")
            go = west.new_command("uav1", "direct", {"action": "takeoff"})
            assert (await west.command("uav1", go)).accepted
            took = await east.command(
                "uav1", east.new_command("uav1", "direct", {"action": "takeoff"})
            )
            assert not took.accepted and "held by pilot@west" in took.reason
            for stop in ("hover", "land", "emergency"):
                reply = await east.command(
                    "uav1", east.new_command("uav1", "direct", {"action": stop})
                )
                assert reply.accepted, reply.reason
            assert drone.done == ["takeoff", "hover", "land", "emergency"]
        finally:
            west.close()
            east.close()
            cv.close()
            pilot.close()
            session.close()

    asyncio.run(main())


def test_a_stop_goes_ahead_of_queued_commands_and_supersedes_them(console: ConsoleBus) -> None:
    async def main() -> None:
        assert console.session is not None
        drone = FakeDrone()
        session, cv = await vehicle(console, "uav1", drone)
        c = BusCommander(console.session, "default", "west")
        try:
            await until_answered(c, "uav1")
            slow = asyncio.ensure_future(
                c.command("uav1", c.new_command("uav1", "direct", {"action": "takeoff", "wait": 1}))
            )
            await asyncio.sleep(0)
            wait_for_queue = c.new_command("uav1", "fault", {"kind": "wind"})
            queued = asyncio.ensure_future(c.command("uav1", wait_for_queue))
            while len(cv._queue) < 1:  # the fault waits behind the takeoff
                await asyncio.sleep(0.01)
            land = await c.command("uav1", c.new_command("uav1", "direct", {"action": "land"}))
            assert land.accepted and drone.done == ["land"]  # ahead of the running takeoff
            superseded = await queued
            assert (
                not superseded.accepted and superseded.reason == "superseded by land before it ran"
            )
            drone.release.set()
            assert (await slow).accepted
            assert drone.done == ["land", "takeoff"]
        finally:
            c.close()
            cv.close()
            session.close()

    asyncio.run(main())


def test_an_observer_cannot_command_and_nothing_flies(console: ConsoleBus) -> None:
    async def main() -> None:
        drone = FakeDrone()
        session, cv = await vehicle(console, "uav1", drone)
        observer = session_as(console, OBSERVER_USER)
        pilot = session_as(console, PILOT_USER)
        try:
            await until_answered(BusCommander(pilot, "default", "p"), "uav1")
            o = BusCommander(observer, "default", "watcher")
            with pytest.raises(NoReply, match="not allowed to command it"):
                await o.command("uav1", o.new_command("uav1", "direct", {"action": "takeoff"}), 3)
            assert drone.done == []
        finally:
            cv.close()
            observer.close()
            pilot.close()
            session.close()

    asyncio.run(main())


def test_a_malformed_command_is_refused_with_a_clear_reason_in_the_log(
    console: ConsoleBus, caplog: pytest.LogCaptureFixture
) -> None:
    async def main() -> list[Any]:
        drone = FakeDrone()
        session, cv = await vehicle(console, "uav1", drone)
        pilot = session_as(console, PILOT_USER)
        try:
            await until_answered(BusCommander(pilot, "default", "p"), "uav1")
            replies = await asyncio.to_thread(
                lambda: list(
                    pilot.get(
                        keys.command("default", "uav1"),
                        payload=json.dumps(
                            {"id": "x1", "op": "direct", "args": {"action": "loop"}}
                        ),
                        timeout=5,
                    )
                )
            )
            assert drone.done == []
            return replies
        finally:
            cv.close()
            pilot.close()
            session.close()

    with caplog.at_level(logging.WARNING, logger="drone.bus.commanded"):
        replies = asyncio.run(main())
    assert len(replies) == 1 and replies[0].ok is not None
    reply = decode_reply(replies[0].ok.payload.to_bytes())
    assert not reply.accepted and reply.id == "x1"
    assert reply.reason.startswith("malformed command: command ")
    assert "uav1: command refused: malformed command: command" in caplog.text


def test_status_and_camera_reach_a_console(console: ConsoleBus) -> None:
    async def main() -> None:
        assert console.session is not None
        session, cv = await vehicle(console, "uav1", FakeDrone())
        c = BusCommander(console.session, "default", "west")
        try:
            await until_answered(c, "uav1")
            for _ in range(200):
                cv.publish_status(Status(drone="uav1", stamp=1.0, mode="FLYING", lease="p@w"))
                cv.publish_camera(b"\xff\xd8 a jpeg")
                await asyncio.sleep(0.02)
                if c.status("uav1") is not None and c.camera("uav1")[1] is not None:
                    break
            assert c.status("uav1").mode == "FLYING"  # type: ignore[union-attr]
            assert c.camera("uav1")[1] == b"\xff\xd8 a jpeg"
        finally:
            c.close()
            cv.close()
            session.close()

    asyncio.run(main())


def test_a_vehicle_cannot_answer_or_publish_as_another(console: ConsoleBus) -> None:
    """uav1's credential declares uav2's queryable and publishes uav2's status: nobody hears."""

    async def main() -> None:
        assert console.session is not None
        drone = FakeDrone()
        cred = console.vehicle_credential("uav1")
        session = open_session(
            client_config(connect=list(cred.connect), user=cred.user, password=cred.password)
        )
        forged = CommandedVehicle(
            session, "default", "uav2", drone.handle, VehicleLease(), asyncio.get_running_loop()
        )
        forged.start()
        c = BusCommander(console.session, "default", "west")
        try:
            for _ in range(20):
                forged.publish_status(Status(drone="uav2", stamp=1.0, mode="FLYING"))
                await asyncio.sleep(0.02)
            with pytest.raises(NoReply):
                await c.command("uav2", c.new_command("uav2", "direct", {"action": "takeoff"}), 2)
            assert drone.done == [] and c.status("uav2") is None
        finally:
            c.close()
            forged.close()
            session.close()

    asyncio.run(main())


def test_a_console_that_joins_another_router_commands_its_vehicles(tmp_path: Path) -> None:
    """Two consoles' routers, the second joined to the first: the vehicle on the first is
    alive on the second, and the second's commands reach it and are answered (what the first
    sends carries no user name on the second: it is trusted by its router id)."""

    async def main() -> None:
        west = ConsoleBus(
            tmp_path / "bus",
            "default",
            ["uav1"],
            name="west",
            listen=[f"tcp/127.0.0.1:{free_port()}"],
        )
        west.start()
        east = ConsoleBus(
            tmp_path / "bus",
            "default",
            ["uav1"],
            name="east",
            listen=[f"tcp/127.0.0.1:{free_port()}"],
            connect=west.listen,
        )
        east.start()
        drone = FakeDrone()
        session, cv = await vehicle(west, "uav1", drone)
        token = session.liveliness().declare_token(keys.alive("default", "uav1"))
        assert east.session is not None
        c = BusCommander(east.session, "default", "east")
        try:
            await until_answered(c, "uav1")
            for _ in range(100):
                if east.alive() == ["uav1"]:
                    break
                await asyncio.sleep(0.05)
            assert east.alive() == ["uav1"]
            reply = await c.command("uav1", c.new_command("uav1", "direct", {"action": "takeoff"}))
            assert reply.accepted and drone.done == ["takeoff"]
        finally:
            token.undeclare()  # type: ignore[no-untyped-call]
            c.close()
            cv.close()
            session.close()
            east.close()
            west.close()

    asyncio.run(main())


def test_a_vehicle_hears_its_consoles_heartbeat_and_clock(console: ConsoleBus) -> None:
    """The console beats at 10 Hz with its clock; a console that stops beating (stalled) is
    silent at once, however long its liveliness lasts."""
    assert console.session is not None
    cred = console.vehicle_credential("uav1")
    session = open_session(
        client_config(connect=list(cred.connect), user=cred.user, password=cred.password)
    )
    now = [100.0]
    clocks: list[float] = []
    presence = ConsolePresence(session, "default", lambda: now[0], on_beat=clocks.append)
    c = BusCommander(console.session, "default", "west")
    try:
        assert presence.last_heard() == 100.0  # joined: heard from now
        now[0] = 101.0
        wait_for(presence.consoles, lambda cs: cs == ["west"], 10, "west's liveliness")
        for _ in range(200):
            c.beat(1_700_000_000.0)
            if clocks:
                break
            time.sleep(0.02)
        assert clocks[0] == 1_700_000_000.0 and presence.last_heard() == 101.0
        now[0] = 105.0  # no beat since: silent 4 s, though its liveliness is still there
        assert presence.last_heard() == 101.0 and presence.consoles() == ["west"]
    finally:
        c.close()
        presence.close()
        session.close()  # type: ignore[no-untyped-call]


def test_a_command_issued_before_a_stop_that_arrives_after_it_is_not_done(
    console: ConsoleBus,
) -> None:
    """A stop travels at real-time priority and may overtake what its console sent before."""

    async def main() -> None:
        assert console.session is not None
        drone = FakeDrone()
        session, cv = await vehicle(console, "uav1", drone)
        c = BusCommander(console.session, "default", "west")
        try:
            await until_answered(c, "uav1")
            land = c.new_command("uav1", "direct", {"action": "land"}, issued=1000.0)
            assert (await c.command("uav1", land)).accepted
            late = c.new_command("uav1", "direct", {"action": "takeoff"}, issued=999.5)
            reply = await c.command("uav1", late)
            assert not reply.accepted and reply.reason == "superseded by a stop issued after it"
            other = BusCommander(console.session, "default", "east")  # its own clock
            try:
                east = other.new_command("uav1", "lease", {"action": "status"}, issued=999.0)
                assert (await other.command("uav1", east)).accepted
            finally:
                other.close()
            after = c.new_command("uav1", "direct", {"action": "takeoff"}, issued=1000.5)
            assert (await c.command("uav1", after)).accepted
            assert drone.done == ["land", "takeoff"]
        finally:
            c.close()
            cv.close()
            session.close()

    asyncio.run(main())
