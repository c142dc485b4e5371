"""The central role's bus parts on real Zenoh routers on loopback: two consoles' routers (one
joins the other, as ``serve --bus-connect`` does, with the fleet's credentials and access
control), a vehicle client on both, the consoles' presence and role tokens, replicas, LTM
statuses and plans as queries."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import pytest

from drone.bus.central import CentralBus
from drone.bus.commanded import ConsolePresence
from drone.bus.config import router_id
from drone.bus.console import ConsoleBus
from drone.bus.plans import VehiclePlans
from drone.bus.vehicle import VehicleBus
from tests.support.loopback import free_port
from tests.support.polling import until_async, wait_for


@dataclass
class Console:
    router: ConsoleBus
    central: CentralBus
    replicas: list[bytes] = field(default_factory=list)
    statuses: list[tuple[str, bytes]] = field(default_factory=list)


@dataclass
class Fleet:
    a: Console
    b: Console
    vehicle: VehicleBus
    bus_a: str
    bus_b: str


@pytest.fixture
async def fleet(tmp_path: Path) -> AsyncIterator[Fleet]:
    loop = asyncio.get_running_loop()
    bus_a, bus_b = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    consoles = []
    for name, listen, connect in (("console-a", bus_a, []), ("console-b", bus_b, [bus_a])):
        router = ConsoleBus(
            tmp_path / "bus", "default", ["uav1"], listen=[listen], connect=connect, name=name
        )
        router.start()
        assert router.session is not None
        replicas: list[bytes] = []
        statuses: list[tuple[str, bytes]] = []
        central = CentralBus(
            router.session,
            "default",
            name,
            loop,
            on_replica=replicas.append,
            on_ltm=lambda d, b, into=statuses: into.append((d, b)),
        )
        central.start()
        consoles.append(Console(router, central, replicas, statuses))
    a, b = consoles
    cred = a.router.vehicle_credential("uav1")
    vehicle = VehicleBus([bus_a, bus_b], cred.user, cred.password, "default", "uav1")
    vehicle.start()
    try:
        yield Fleet(a, b, vehicle, bus_a, bus_b)
    finally:
        vehicle.close()
        for c in (b, a):
            c.central.close()
            c.router.close()


async def test_each_console_sees_the_other_and_the_holder(fleet: Fleet) -> None:
    both = {"console-a", "console-b"}
    # the joining router is not authenticated by the one it joins: without the peer's id in
    # its access control, console-b would not see console-a's tokens
    await until_async(lambda: fleet.b.central.view()[0] == both, 10.0, "console-b sees console-a")
    await until_async(lambda: fleet.a.central.view()[0] == both, 10.0, "console-a sees console-b")
    fleet.a.central.claim()
    await until_async(
        lambda: fleet.b.central.view()[1] == {"console-a"}, 10.0, "console-b sees the holder"
    )
    fleet.a.central.release()
    await until_async(lambda: fleet.b.central.view()[1] == set(), 10.0, "the holder's token gone")


async def test_a_console_has_one_presence_token_for_the_vehicles_and_the_election(
    fleet: Fleet,
) -> None:
    """``uavc/<fleet>/console/<name>/alive``, declared by the console's router, is what the
    vehicles watch their consoles by and whom the election counts; it goes with the router."""
    both = {"console-a", "console-b"}
    session = fleet.vehicle.session
    assert session is not None
    presence = ConsolePresence(session, "default", time.monotonic)
    try:
        await until_async(lambda: fleet.a.central.view()[0] == both, 10.0, "a sees b")
        await until_async(lambda: set(presence.consoles()) == both, 10.0, "the vehicle's view")

        def tokens() -> set[str]:
            return {
                str(r.ok.key_expr)
                for r in session.liveliness().get("uavc/default/**", timeout=5)
                if r.ok is not None
            }

        expected = {
            "uavc/default/console/console-a/alive",
            "uavc/default/console/console-b/alive",
            "uavc/default/uav1/alive",
        }
        # a liveliness get may end before a joined router's answer arrives: ask until it is in
        seen: set[str] = set()
        for _ in range(10):
            seen = await asyncio.to_thread(tokens)
            if seen == expected:
                break
        assert seen == expected
        fleet.b.central.close()
        fleet.b.router.close()
        await until_async(lambda: fleet.a.central.view()[0] == {"console-a"}, 10.0, "b gone")
        await until_async(lambda: presence.consoles() == ["console-a"], 10.0, "b gone too")
    finally:
        presence.close()


async def test_the_routers_ids_derive_from_the_consoles_names(fleet: Fleet) -> None:
    assert fleet.a.router.router is not None
    assert str(fleet.a.router.router.info.zid()) == router_id("default", "console-a")
    assert router_id("default", "console-a") != router_id("default", "console-b")


async def test_replicas_reach_the_standby_and_plans_reach_the_vehicle(fleet: Fleet) -> None:
    loop = asyncio.get_running_loop()
    await until_async(
        lambda: fleet.b.central.view()[0] == {"console-a", "console-b"}, 10.0, "joined"
    )
    fleet.a.central.publish_replica(b'{"console": "console-a"}')
    await until_async(lambda: fleet.b.replicas, 10.0, "the replica at console-b")
    assert fleet.b.replicas == [b'{"console": "console-a"}']

    async def on_plan(payload: bytes) -> bytes:
        plan = json.loads(payload)
        return json.dumps({"accepted": True, "reason": "ok", "plan_id": plan["plan_id"]}).encode()

    assert fleet.vehicle.session is not None
    plans = VehiclePlans(fleet.vehicle.session, "default", "uav1", loop, on_plan)
    plans.start()
    try:
        plans.publish_status(b'{"name": "uav1"}')
        await until_async(lambda: fleet.b.statuses, 10.0, "the LTM status at console-b")
        assert fleet.b.statuses[0] == ("uav1", b'{"name": "uav1"}')
        # both consoles reach it: console-a directly, console-b through console-a's router
        for console in (fleet.a, fleet.b):
            raw = await console.central.send_plan("uav1", b'{"plan_id": 7}', 5.0)
            assert json.loads(raw) == {"accepted": True, "reason": "ok", "plan_id": 7}
        # the vehicle sees the central's token come and go
        assert not plans.central_alive
        fleet.b.central.claim()
        await until_async(lambda: plans.central_alive, 10.0, "the vehicle sees a central")
        assert plans.central_name == "console-b"
        fleet.b.central.release()
        await until_async(lambda: not plans.central_alive, 10.0, "the vehicle sees none")
    finally:
        plans.close()


async def test_a_plan_to_a_vehicle_that_is_not_there_is_a_clear_error(fleet: Fleet) -> None:
    from drone.bus.errors import BusError

    with pytest.raises(BusError, match="uav9 did not answer"):
        await fleet.a.central.send_plan("uav9", b"{}", 0.5)


def test_a_console_that_starts_first_joins_the_other_when_it_comes_and_again_after_it_restarts(
    tmp_path: Path,
) -> None:
    """``serve --bus-connect`` started before the console it joins: it keeps dialling, joins
    when the other's router comes (and sees what is on it), and joins again when that router
    restarts on the same port with the same id."""
    bus_a, bus_b = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"

    def console(name: str, listen: str, connect: list[str]) -> ConsoleBus:
        bus = ConsoleBus(
            tmp_path / "bus", "default", ["uav1"], name=name, listen=[listen], connect=connect
        )
        bus.start()
        return bus

    b = console("console-b", bus_b, [bus_a])
    a: ConsoleBus | None = None
    vehicle: VehicleBus | None = None
    try:
        assert [(j.endpoint, j.joined) for j in b.joins()] == [(bus_a, False)]
        a = console("console-a", bus_a, [])
        cred = a.vehicle_credential("uav1")
        vehicle = VehicleBus([bus_a], cred.user, cred.password, "default", "uav1")
        vehicle.start()
        wait_for(b.alive, lambda alive: alive == ["uav1"], 15, "uav1, on console-a, at console-b")
        # the join's status follows the redial's answer, which may come after the first token
        wait_for(
            b.joins,
            lambda js: [(j.endpoint, j.joined) for j in js] == [(bus_a, True)],
            15,
            "joined",
        )
        a.close()
        wait_for(b.joins, lambda js: not js[0].joined, 15, "console-a's router gone")
        assert b.alive() == []
        a = console("console-a", bus_a, [])  # the same port, the same id
        wait_for(b.joins, lambda js: js[0].joined, 15, "console-a's router back")
        wait_for(b.alive, lambda alive: alive == ["uav1"], 15, "uav1 back at console-b")
    finally:
        if vehicle is not None:
            vehicle.close()
        if a is not None:
            a.close()
        b.close()


@dataclass
class _Sample:
    key_expr: str
    kind: object


def test_the_view_settles_after_a_relink_only_not_on_a_consoles_first_looks() -> None:
    """No network: the view as the liveliness callbacks fill it, on an injected clock. A
    console's first looks follow the bus as its history arrives (they froze on the first one:
    a central token that came a moment after it was never seen); off its router and for
    RELINK_SETTLE_S after a relink the view is the last one seen."""
    import zenoh

    from drone.bus.central import RELINK_SETTLE_S

    routers: list[bytes] = [b"router"]
    session = SimpleNamespace(info=SimpleNamespace(routers_zid=lambda: list(routers)))
    now = [100.0]
    central = CentralBus(
        session,  # type: ignore[arg-type]
        "default",
        "west",
        None,  # type: ignore[arg-type]
        on_replica=lambda _b: None,
        on_ltm=lambda _d, _b: None,
    )
    central.clock = lambda: now[0]
    put, gone = zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE
    assert central.view() == ({"west"}, set())
    central._on_console(_Sample("uavc/default/console/east/alive", put))  # type: ignore[arg-type]
    central._on_holder(_Sample("uavc/default/central/alive/east", put))  # type: ignore[arg-type]
    seen = ({"west", "east"}, {"east"})
    assert central.view() == seen  # at the same instant: no settling on first looks
    routers.clear()  # off its router: east's tokens go with the link
    central._on_holder(_Sample("uavc/default/central/alive/east", gone))  # type: ignore[arg-type]
    central._on_console(_Sample("uavc/default/console/east/alive", gone))  # type: ignore[arg-type]
    assert central.view() == seen
    routers.append(b"router")  # linked again, the history not back yet
    now[0] += RELINK_SETTLE_S / 2
    assert central.view() == seen
    now[0] += RELINK_SETTLE_S
    assert central.view() == ({"west"}, set())  # settled: what the bus says
