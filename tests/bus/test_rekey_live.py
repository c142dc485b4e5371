"""A console's router restarted for new vehicle keys (``ConsoleBus.rekey``), on a real bus on
loopback: who is let in after it, who rejoins by themselves, the commands held through it
(stops first, none lost), and the central's election not fooled by the moment off the bus."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from drone.bus import keys
from drone.bus.central import CentralBus
from drone.bus.commander import BusCommander
from drone.bus.commands import Command, CommandReply, decode_command, encode_reply
from drone.bus.config import CONSOLE_USER, client_config
from drone.bus.console import ConsoleBus
from drone.bus.credentials import read_dictionary
from drone.bus.errors import BusConfigError, NoReply
from drone.bus.session import open_session
from tests.support.loopback import free_port
from tests.support.polling import until, wait_for

KEY7 = "uavk_" + "7" * 43
KEY8 = "uavk_" + "8" * 43


@pytest.fixture
def bus(tmp_path: Path) -> Iterator[ConsoleBus]:
    """A console started with uav7's key (as ``serve`` with one key made before it)."""
    console = ConsoleBus(
        tmp_path / "bus",
        "default",
        [],
        name="west",
        listen=[f"tcp/127.0.0.1:{free_port()}"],
        vehicle_passwords={"uav7": KEY7},
    )
    console.start()
    yield console
    console.close()


TOKENS: list[zenoh.LivelinessToken] = []  # a token undeclares itself when dropped


def join(bus: ConsoleBus, name: str, key: str) -> zenoh.Session:
    """A vehicle's session (raises BusConfigError when the router refuses it) with its token."""
    session = open_session(
        client_config(connect=bus.client_endpoints, user=f"vehicle-{name}", password=key)
    )
    TOKENS.append(session.liveliness().declare_token(keys.alive("default", name)))
    return session


def test_a_new_key_opens_the_bus_and_the_vehicles_on_it_rejoin(bus: ConsoleBus) -> None:
    v7 = join(bus, "uav7", KEY7)
    try:
        wait_for(bus.alive, lambda a: a == ["uav7"], 10, "uav7 alive")
        with pytest.raises(BusConfigError):
            join(bus, "uav8", KEY8).close()
        endpoints = list(bus.client_endpoints)

        done = bus.rekey({"uav7": KEY7, "uav8": KEY8})

        assert done is not None and done.added == ("uav8",) and not done.removed
        assert bus.client_endpoints == endpoints  # the same endpoint: clients redial it
        assert "vehicle-uav8" in read_dictionary(bus.directory / "credentials.txt")
        v8 = join(bus, "uav8", KEY8)
        try:
            wait_for(bus.alive, lambda a: a == ["uav7", "uav8"], 10, "uav7 back, uav8 in")
        finally:
            v8.close()  # type: ignore[no-untyped-call]
        with pytest.raises(BusConfigError):
            join(bus, "uav8", KEY7).close()  # another vehicle's key
        assert bus.rekey({"uav7": KEY7, "uav8": KEY8}) is None  # nothing changed: left as is
        assert len(bus.rekeys) == 1
    finally:
        v7.close()  # type: ignore[no-untyped-call]


def test_a_revoked_key_is_cut_off_and_refused(bus: ConsoleBus) -> None:
    v7 = join(bus, "uav7", KEY7)
    try:
        wait_for(bus.alive, lambda a: a == ["uav7"], 10, "uav7 alive")
        done = bus.rekey({})
        assert done is not None and done.removed == ("uav7",)
        assert "vehicle-uav7" not in read_dictionary(bus.directory / "credentials.txt")
        wait_for(bus.alive, lambda a: a == [], 10, "uav7 cut off")
        with pytest.raises(BusConfigError):
            join(bus, "uav7", KEY7).close()
    finally:
        v7.close()  # type: ignore[no-untyped-call]


def test_a_replaced_key_is_refused_and_the_new_one_taken(bus: ConsoleBus) -> None:
    done = bus.rekey({"uav7": KEY8})
    assert done is not None and done.changed == ("uav7",)
    with pytest.raises(BusConfigError):
        join(bus, "uav7", KEY7).close()
    join(bus, "uav7", KEY8).close()  # type: ignore[no-untyped-call]


def test_a_key_revoked_while_the_console_was_down_is_refused_at_its_start(
    bus: ConsoleBus,
) -> None:
    bus.close()
    again = ConsoleBus(
        bus.directory, "default", [], name="west", listen=list(bus.listen), vehicle_passwords={}
    )
    again.start()
    try:
        assert "vehicle-uav7" not in read_dictionary(bus.directory / "credentials.txt")
        with pytest.raises(BusConfigError):
            join(again, "uav7", KEY7).close()
    finally:
        again.close()


class Vehicle:
    """A vehicle's ``cmd`` queryable: records each command's op and action as it arrives."""

    def __init__(self, bus: ConsoleBus, name: str, key: str) -> None:
        self.session = join(bus, name, key)
        self.name = name
        self.got: list[str] = []
        self._q = self.session.declare_queryable(keys.command("default", name), self._on)

    def _on(self, query: zenoh.Query) -> None:
        assert query.payload is not None
        command = decode_command(query.payload.to_bytes())
        self.got.append(str(command.args.get("action", command.op)))
        reply = CommandReply(id=command.id, drone=self.name, accepted=True)
        query.reply(query.key_expr, encode_reply(reply))

    def close(self) -> None:
        self._q.undeclare()  # type: ignore[no-untyped-call]
        self.session.close()  # type: ignore[no-untyped-call]


def direct(commander: BusCommander, action: str) -> Command:
    return commander.new_command("uav7", "direct", {"action": action})


def test_commands_held_through_a_restart_go_after_it_stops_first(bus: ConsoleBus) -> None:
    """What a console sends while its router restarts waits for it and then reaches the
    vehicle, the land before the takeoff that was sent before it; none is lost."""
    v7 = Vehicle(bus, "uav7", KEY7)
    assert bus.session is not None
    commander = BusCommander(bus.session, "default", "west")

    async def scenario() -> list[CommandReply]:
        wait_for(bus.alive, lambda a: a == ["uav7"], 10, "uav7 alive")
        assert (await commander.command("uav7", direct(commander, "hover"))).accepted
        commander.hold()
        assert await commander.drained(1.0)
        takeoff = asyncio.create_task(commander.command("uav7", direct(commander, "takeoff")))
        land = asyncio.create_task(commander.command("uav7", direct(commander, "land")))
        await asyncio.sleep(0)  # both are held now
        done = await asyncio.to_thread(bus.rekey, {"uav7": KEY7, "uav8": KEY8})
        assert done is not None
        await asyncio.to_thread(
            wait_for, bus.alive, lambda a: a == ["uav7"], 10, "uav7 back on the bus"
        )
        commander.release()
        return list(await asyncio.gather(land, takeoff))

    try:
        replies = asyncio.run(scenario())
        assert all(r.accepted for r in replies)
        assert v7.got == ["hover", "land", "takeoff"]
    finally:
        commander.close()
        v7.close()


def test_a_command_held_too_long_says_it_was_not_sent(
    bus: ConsoleBus, monkeypatch: pytest.MonkeyPatch
) -> None:
    from drone.bus import commander as commander_module

    monkeypatch.setattr(commander_module, "HOLD_MAX_S", 0.05)
    assert bus.session is not None
    commander = BusCommander(bus.session, "default", "west")
    commander.hold()
    try:
        with pytest.raises(NoReply, match="not sent: the bus was restarting"):
            asyncio.run(commander.command("uav7", direct(commander, "land")))
    finally:
        commander.close()


def test_the_election_keeps_its_view_while_the_router_restarts(bus: ConsoleBus) -> None:
    """Off its router for a moment, a console sees no other console: its election must go
    on the view it had (else a standby would claim the central role at once)."""
    assert bus.session is not None and bus.credentials is not None
    east = open_session(
        client_config(
            connect=bus.client_endpoints,
            user=CONSOLE_USER,
            password=bus.credentials.password(CONSOLE_USER),
        )
    )
    presence = east.liveliness().declare_token(keys.console_alive("default", "east"))
    central_token = east.liveliness().declare_token("uavc/default/central/alive/east")

    async def scenario() -> None:
        central = CentralBus(
            bus.session,
            "default",
            "west",
            asyncio.get_running_loop(),
            on_replica=lambda _b: None,
            on_ltm=lambda _d, _b: None,
        )
        central.start()
        now = [100.0]
        central.clock = lambda: now[0]
        try:
            seen = await asyncio.to_thread(
                wait_for, central.view, lambda v: v[1] == {"east"}, 10, "east central"
            )
            assert seen == ({"west", "east"}, {"east"})
            assert bus.router is not None
            bus.router.close()  # type: ignore[no-untyped-call]
            bus.router = None  # what a restart does first
            session = bus.session
            assert session is not None
            await asyncio.to_thread(
                until, lambda: not session.info.routers_zid(), 10, "west off its router"
            )
            assert central.view() == seen  # not: west alone, no holder
            await asyncio.to_thread(bus.rekey, {"uav7": KEY7})  # the router opens again
            assert central.view() == seen  # settling
            await asyncio.to_thread(until, east.info.routers_zid, 10, "east back")
            now[0] += 1.0
            await asyncio.to_thread(  # settled: the view from the bus again, east in it
                until, lambda: central.view() == seen, 10, "east in the view from the bus"
            )
        finally:
            central.close()

    try:
        asyncio.run(scenario())
    finally:
        central_token.undeclare()  # type: ignore[no-untyped-call]
        presence.undeclare()  # type: ignore[no-untyped-call]
        east.close()  # type: ignore[no-untyped-call]
