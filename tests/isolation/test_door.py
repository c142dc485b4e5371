"""The safety door: its protocol and tickets (Hypothesis), the stop ledger, and the door itself
on loopback with a real WebSocket client (websockets): the auth deadline, the caps that keep a
held connection from being displaced (a flood of connections without a token), refused
tokens and roles, the frame cap, dedupe by stop id and supersede, TLS for a page on the LAN."""

from __future__ import annotations

import asyncio
import contextlib
import json
import ssl
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from websockets.asyncio.client import ClientConnection, connect
from websockets.client import ClientProtocol
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.frames import Frame
from websockets.protocol import State
from websockets.uri import parse_uri

from server.http.tls import ensure_server_cert, server_context
from server.vehicles.door import DoorLimits, SafetyDoor, door_authenticator
from server.vehicles.door_protocol import (
    MAX_FRAME_BYTES,
    Ack,
    Auth,
    DoorPhase,
    DoorSession,
    Error,
    Heartbeat,
    Hello,
    Stop,
    Supersede,
    Superseded,
    encode,
    parse_client,
    parse_door,
)
from server.vehicles.errors import DoorError, DoorProtocolError, TicketError
from server.vehicles.stops import StopLedger
from server.vehicles.tickets import DoorSecrets, mint, verify
from tests.support.loopback import fresh_address
from tests.support.polling import until_async

SECRET = b"k" * 32
TOKEN = "pilot-token-for-door-tests"

# ------------------------------------------------------------------------------ protocol

ids = st.from_regex(r"[A-Za-z0-9_.:-]{1,64}", fullmatch=True)
times = st.floats(min_value=0, max_value=4e9, allow_nan=False)
actions = st.sampled_from(["emergency", "land", "hover"])
client_messages = st.one_of(
    st.builds(Auth, st.text(min_size=1, max_size=200)),
    st.builds(Stop, actions, ids, st.one_of(st.none(), times)),
    st.builds(Supersede, st.lists(ids, max_size=32).map(tuple)),
)
door_messages = st.one_of(
    st.builds(Hello, st.text(min_size=1, max_size=32), times, st.just(0.25)),
    st.builds(Heartbeat, times, st.sampled_from(["LANDED", "FLYING"]), st.booleans()),
    st.builds(
        Ack,
        ids,
        actions,
        st.booleans(),
        st.text(max_size=200),
        st.one_of(st.none(), times),
        st.sampled_from(["door", "server"]),
        st.one_of(st.none(), times),
    ),
    st.builds(Superseded, st.lists(ids, max_size=5).map(tuple), st.lists(ids).map(tuple)),
    st.builds(Error, st.text(max_size=200)),
)


@given(st.one_of(st.text(max_size=300), st.binary(max_size=300)))
def test_any_frame_parses_or_raises_the_protocol_error(frame: str | bytes) -> None:
    for parse in (parse_client, parse_door):
        with contextlib.suppress(DoorProtocolError):
            parse(frame)


@given(
    st.dictionaries(
        st.sampled_from(["op", "token", "action", "id", "issued", "ids", "t", "detail"]),
        st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(), st.lists(ids)),
    )
)
def test_any_object_parses_or_raises_the_protocol_error(obj: dict[str, Any]) -> None:
    text = json.dumps(obj)
    for parse in (parse_client, parse_door):
        with contextlib.suppress(DoorProtocolError):
            parse(text)


@given(client_messages)
def test_client_messages_round_trip(msg: Any) -> None:
    assert parse_client(encode(msg)) == msg


@given(door_messages)
def test_door_messages_round_trip(msg: Any) -> None:
    assert parse_door(encode(msg)) == msg


@pytest.mark.parametrize(
    ("frame", "why"),
    [
        ('{"op":"stop","action":"takeoff","id":"a"}', "action"),
        ('{"op":"stop","action":"land","id":"a b"}', "stop id"),
        ('{"op":"stop","action":"land","id":"a","issued":NaN}', "JSON"),
        ('{"op":"stop","action":"land","id":"a","issued":-5}', "unix time"),
        ('{"op":"stop","action":"land","id":"a","issued":true}', "finite number"),
        ('{"op":"auth","token":""}', "token"),
        ('{"op":"supersede","ids":"a"}', "ids"),
        ('{"op":"publish"}', "unknown op"),
        ("[1]", "object"),
        ("{", "JSON"),
        ('{"op":"auth","token":"' + "x" * MAX_FRAME_BYTES + '"}', "4096"),
    ],
)
def test_refused_frames_say_why(frame: str, why: str) -> None:
    with pytest.raises(DoorProtocolError, match=why):
        parse_client(frame)


def test_session_takes_auth_first_then_stops_and_keeps_the_beat() -> None:
    s = DoorSession(accepted_at=100.0, auth_deadline_s=1.0)
    assert not s.overdue(100.9) and s.overdue(101.0)
    assert isinstance(s.receive('{"op":"auth","token":"t"}'), Auth)
    s.authenticated("pilot", now=100.5)
    assert s.phase is DoorPhase.OPEN and not s.overdue(200.0)
    assert [s.heartbeat_due(t) for t in (100.6, 100.75, 100.8, 101.0)] == [
        False,
        True,
        False,
        True,
    ]
    assert s.heartbeat_due(105.0) and not s.heartbeat_due(105.1)  # after a stall: no burst
    assert isinstance(s.receive('{"op":"stop","action":"land","id":"x"}'), Stop)
    with pytest.raises(DoorProtocolError):  # a bad frame is refused, the connection stays
        s.receive("nope")
    assert s.phase is DoorPhase.OPEN
    with pytest.raises(DoorProtocolError, match="already"):
        s.receive('{"op":"auth","token":"t"}')
    assert s.phase is DoorPhase.CLOSED


def test_session_closes_on_anything_but_auth_first() -> None:
    s = DoorSession(0.0)
    with pytest.raises(DoorProtocolError, match="authenticate first"):
        s.receive('{"op":"stop","action":"emergency","id":"x"}')
    assert s.phase is DoorPhase.CLOSED
    garbage = DoorSession(0.0)
    with pytest.raises(DoorProtocolError):
        garbage.receive("GET / HTTP/1.1")
    assert garbage.phase is DoorPhase.CLOSED


# ------------------------------------------------------------------------------ tickets

names = st.from_regex(r"[A-Za-z0-9_-]{1,32}", fullmatch=True)


@given(names, st.sampled_from(["pilot", "observer"]), st.integers(1, 2**40))
def test_tickets_round_trip(drone: str, role: str, expires: int) -> None:
    ticket = mint(SECRET, drone, role, expires)
    assert verify(SECRET, ticket, drone, expires - 1) == role


@given(st.integers(0, 200), st.characters(codec="ascii"))
def test_a_changed_ticket_is_refused(at: int, ch: str) -> None:
    ticket = mint(SECRET, "uav1", "pilot", 2e9)
    at %= len(ticket)
    forged = ticket[:at] + ch + ticket[at + 1 :]
    if forged != ticket:
        with pytest.raises(TicketError):
            verify(SECRET, forged, "uav1", 1e9)


@given(st.text(max_size=200))
def test_any_text_as_a_ticket_is_refused_cleanly(text: str) -> None:
    with pytest.raises(TicketError):
        verify(SECRET, text, "uav1", 1e9)


def test_tickets_expire_name_one_drone_and_one_vehicle_secret() -> None:
    ticket = mint(SECRET, "uav1", "pilot", 1000)
    with pytest.raises(TicketError, match="expired"):
        verify(SECRET, ticket, "uav1", 1000)
    with pytest.raises(TicketError, match="for uav1, not uav2"):
        verify(SECRET, ticket, "uav2", 10)
    with pytest.raises(TicketError, match="signature"):
        verify(b"another vehicle's secret", ticket, "uav1", 10)
    with pytest.raises(TicketError):
        mint(SECRET, "uav1.evil", "pilot", 10)


def test_door_secrets_are_kept_private_and_reused(tmp_path: Path) -> None:
    first = DoorSecrets(tmp_path / "vehicles")
    assert first.get("uav1") is None
    a = first.get_or_create("uav1")
    assert first.get_or_create("uav1") == a and first.get_or_create("uav2") != a
    assert (tmp_path / "vehicles" / "door-secrets.json").stat().st_mode & 0o777 == 0o600
    assert DoorSecrets(tmp_path / "vehicles").get("uav1") == a  # a restarted serve mints alike


def test_the_door_takes_the_pilot_token_or_a_pilot_ticket() -> None:
    auth = door_authenticator(TOKEN, SECRET, "uav1", clock=lambda: 100.0)
    assert auth(TOKEN) == "pilot"
    assert auth(mint(SECRET, "uav1", "pilot", 200)) == "pilot"
    assert auth(mint(SECRET, "uav1", "observer", 200)) == "observer"  # the door refuses it
    for bad in ("nope", mint(SECRET, "uav1", "pilot", 50), mint(SECRET, "uav2", "pilot", 200)):
        with pytest.raises(DoorError):
            auth(bad)
    with pytest.raises(DoorError, match="no tickets"):
        door_authenticator(TOKEN, None, "uav1")(mint(SECRET, "uav1", "pilot", 2e9))


# ------------------------------------------------------------------------------ the ledger


def test_a_stop_runs_once_whichever_road_brings_it_first() -> None:
    ledger = StopLedger()
    first = ledger.admit("s1", "emergency", 100.0, "server", 105.4)
    assert first.run and first.accepted and first.road == "server"
    assert first.late_s == pytest.approx(5.4) and "5.4 s after it was issued" in first.detail
    again = ledger.admit("s1", "emergency", 100.0, "door", 106.0)
    assert not again.run and again.accepted
    assert again.road == "server" and again.delivered == 105.4
    assert "already delivered by the server road" in again.detail
    quick = ledger.admit("s2", "land", None, "door", 1.0)
    assert quick.run and quick.late_s is None and quick.detail == "land delivered"


def test_a_superseded_stop_never_runs_and_one_that_ran_is_said_so() -> None:
    ledger = StopLedger()
    ledger.admit("ran", "land", 1.0, "door", 1.1)
    assert ledger.supersede(("pending", "ran"), 2.0) == (("pending",), ("ran",))
    late = ledger.admit("pending", "emergency", 1.5, "server", 9.0)
    assert not late.run and not late.accepted and "superseded" in late.detail


def test_the_ledger_is_bounded() -> None:
    ledger = StopLedger(capacity=3)
    for i in range(10):
        ledger.admit(f"s{i}", "hover", None, "door", float(i))
        ledger.supersede((f"x{i}",), float(i))
    assert ledger.delivered("s0") is None and ledger.delivered("s9") is not None
    assert len(ledger._delivered) == 3 and len(ledger._superseded) == 3


# ------------------------------------------------------------------------------ on loopback

HOST = fresh_address()


class Vehicle:
    """What the door calls: a ledger and a record of what reached the "drone"."""

    def __init__(self) -> None:
        self.ledger = StopLedger()
        self.ran: list[tuple[str, str]] = []

    def on_stop(self, stop: Stop) -> Ack:
        v = self.ledger.admit(stop.id, stop.action, stop.issued, "door", time.time())
        if v.run:
            self.ran.append((stop.action, stop.id))
        return Ack(stop.id, stop.action, v.accepted, v.detail, v.delivered, v.road, v.late_s)

    def on_supersede(self, msg: Supersede) -> Superseded:
        return Superseded(*self.ledger.supersede(msg.ids, time.time()))


@contextlib.asynccontextmanager
async def running_door(
    limits: DoorLimits | None = None, tls: ssl.SSLContext | None = None, host: str = HOST
) -> AsyncIterator[tuple[SafetyDoor, Vehicle]]:
    vehicle = Vehicle()
    door = SafetyDoor(
        host,
        0,
        drone="uav1",
        authenticate=door_authenticator(TOKEN, SECRET, "uav1"),
        on_stop=vehicle.on_stop,
        on_supersede=vehicle.on_supersede,
        status=lambda: ("FLYING", True),
        tls=tls,
        limits=limits,
    )
    await door.start()
    try:
        yield door, vehicle
    finally:
        await door.stop()


async def recv(ws: ClientConnection, timeout: float = 10.0) -> Any:
    return parse_door(await asyncio.wait_for(ws.recv(), timeout))


async def recv_op(ws: ClientConnection, kind: type, timeout: float = 10.0) -> Any:
    """The next message of ``kind`` (heartbeats in between are skipped)."""
    deadline = time.monotonic() + timeout
    while True:
        msg = await recv(ws, max(0.01, deadline - time.monotonic()))
        if isinstance(msg, kind):
            return msg


async def opened(door: SafetyDoor, token: str = TOKEN, **kw: Any) -> ClientConnection:
    ws = await connect(door.url, **kw)
    await ws.send(encode(Auth(token)))
    hello = await recv(ws)
    assert isinstance(hello, Hello) and hello.drone == "uav1" and hello.heartbeat_s == 0.25
    return ws


async def closed_with(ws: ClientConnection, timeout: float = 10.0) -> tuple[int, str]:
    with pytest.raises(ConnectionClosed) as info:
        while True:
            await asyncio.wait_for(ws.recv(), timeout)
    rcvd = info.value.rcvd
    return (rcvd.code, rcvd.reason) if rcvd is not None else (1006, "")


async def test_hello_heartbeats_and_a_stop_acked_once_per_id() -> None:
    async with running_door() as (door, vehicle):
        ws = await opened(door, mint(SECRET, "uav1", "pilot", time.time() + 60))
        beat = await recv_op(ws, Heartbeat)
        assert beat.state == "FLYING" and beat.link_ok and abs(beat.t - time.time()) < 60
        await ws.send(encode(Stop("emergency", "s-1", time.time())))
        ack = await recv_op(ws, Ack)
        assert (ack.id, ack.action, ack.accepted, ack.road) == ("s-1", "emergency", True, "door")
        assert ack.delivered is not None
        await ws.send(encode(Stop("emergency", "s-1", time.time())))
        again = await recv_op(ws, Ack)
        assert again.accepted and "already delivered by the door road" in again.detail
        assert vehicle.ran == [("emergency", "s-1")]
        await ws.close()


async def test_supersede_drops_a_stop_that_comes_later_down_any_road() -> None:
    async with running_door() as (door, vehicle):
        ws = await opened(door)
        await ws.send(encode(Stop("land", "ran", None)))
        await recv_op(ws, Ack)
        await ws.send(encode(Supersede(("pending", "ran"))))
        answer = await recv_op(ws, Superseded)
        assert answer.ids == ("pending",) and answer.too_late == ("ran",)
        # the same stop, late, down the server road
        late = vehicle.ledger.admit("pending", "emergency", None, "server", time.time())
        assert not late.run and not late.accepted
        await ws.send(encode(Stop("emergency", "pending", None)))
        refused = await recv_op(ws, Ack)
        assert not refused.accepted and "superseded" in refused.detail
        assert vehicle.ran == [("land", "ran")]
        await ws.close()


async def test_supersede_read_with_its_stop_wins_over_it() -> None:
    """A stop and the supersede behind it, read together (the vehicle was stopped while both
    came in): the stop does not fire from the past. The frames are written in one segment
    by a client on websockets' sans-I/O protocol, so the door reads them together."""
    async with running_door() as (door, vehicle):
        reader, writer = await asyncio.open_connection(HOST, door.port)
        client = ClientProtocol(parse_uri(door.url))
        client.send_request(client.connect())
        writer.write(b"".join(client.data_to_send()))
        while client.handshake_exc is None and client.state is not State.OPEN:
            client.receive_data(await asyncio.wait_for(reader.read(4096), 10))
        client.send_text(encode(Auth(TOKEN)).encode())
        writer.write(b"".join(client.data_to_send()))
        got: list[Any] = []
        while not any(isinstance(m, Hello) for m in got):
            client.receive_data(await asyncio.wait_for(reader.read(4096), 10))
            got += [parse_door(e.data) for e in client.events_received() if isinstance(e, Frame)]
        client.send_text(encode(Stop("emergency", "old", 1.0)).encode())
        client.send_text(encode(Supersede(("old",))).encode())
        writer.write(b"".join(client.data_to_send()))
        while not any(isinstance(m, Ack) for m in got):
            client.receive_data(await asyncio.wait_for(reader.read(4096), 10))
            got += [parse_door(e.data) for e in client.events_received() if isinstance(e, Frame)]
        superseded = next(m for m in got if isinstance(m, Superseded))
        ack = next(m for m in got if isinstance(m, Ack))
        assert superseded.ids == ("old",) and not ack.accepted and "superseded" in ack.detail
        assert vehicle.ran == []
        writer.close()


async def test_no_auth_within_the_deadline_is_closed() -> None:
    limits = DoorLimits(auth_deadline_s=0.3)
    async with running_door(limits) as (door, _):
        ws = await connect(door.url)  # the handshake, then nothing
        code, reason = await closed_with(ws)
        # "try again later" (1013), not a refusal (1008): a page reconnects at once, where a
        # refused credential makes it wait (web/static/js/door.js), and on a busy machine the
        # deadline passes while the door itself is slow to read the page's auth
        assert (code, reason) == (1013, "no auth within 0.3 s of connecting")
        # a raw TCP connection that never even starts the handshake is let go as well
        reader, writer = await asyncio.open_connection(HOST, door.port)
        assert await asyncio.wait_for(reader.read(), 10) == b""
        writer.close()
        assert door.counts.auth_timeouts == 2 and door.counts.unauthenticated_total == 0


async def test_an_auth_the_door_was_too_busy_to_read_in_time_is_taken() -> None:
    """The door's own loop stalls (a busy machine) past the deadline while the page's
    handshake waits in its socket: the page, on time, is let in (the deadline is judged by a
    read that waited for the client in vain), not closed for the door's own lateness."""
    limits = DoorLimits(auth_deadline_s=0.3)
    async with running_door(limits) as (door, _):
        reader, writer = await asyncio.open_connection(HOST, door.port)
        await until_async(lambda: door.counts.unauthenticated_total == 1, 10, "the accept")
        client = ClientProtocol(parse_uri(door.url))
        client.send_request(client.connect())
        writer.write(b"".join(client.data_to_send()))
        await writer.drain()
        time.sleep(0.45)  # the door's loop (this one) does not run: past the 0.3 s deadline

        async def more() -> bytes:
            data = await asyncio.wait_for(reader.read(4096), 10)
            assert data, f"the door closed ({door.counts.auth_timeouts} auth timeouts)"
            return data

        while client.handshake_exc is None and client.state is not State.OPEN:
            client.receive_data(await more())
        client.send_text(encode(Auth(TOKEN)).encode())
        writer.write(b"".join(client.data_to_send()))
        got: list[Any] = []
        while not got:
            client.receive_data(await more())
            got += [parse_door(e.data) for e in client.events_received() if isinstance(e, Frame)]
        assert isinstance(got[0], Hello) and door.counts.auth_timeouts == 0
        writer.close()


@pytest.mark.parametrize(
    ("token", "why"),
    [
        (mint(SECRET, "uav1", "observer", 2e9), "observer may not stop"),
        ("observer-token-the-vehicle-does-not-know", "pilot token"),
        (mint(SECRET, "uav1", "pilot", 1000), "expired"),
        (mint(b"x" * 32, "uav1", "pilot", 2e9), "signature"),
    ],
)
async def test_refused_tokens_close_with_the_reason(token: str, why: str) -> None:
    async with running_door() as (door, vehicle):
        ws = await connect(door.url)
        await ws.send(encode(Auth(token)))
        code, reason = await closed_with(ws)
        assert code == 1008 and why in reason
        assert door.counts.auth_failed == 1 and vehicle.ran == []


async def test_a_stop_before_auth_is_not_run() -> None:
    async with running_door() as (door, vehicle):
        ws = await connect(door.url)
        await ws.send(encode(Stop("emergency", "x", None)))
        code, reason = await closed_with(ws)
        assert code == 1008 and "authenticate first" in reason and vehicle.ran == []


async def test_frames_are_capped_and_binary_refused() -> None:
    async with running_door() as (door, _):
        ws = await opened(door)
        await ws.send(b"\x00\x01")
        err = await recv_op(ws, Error)
        assert "JSON text" in err.detail
        await ws.send("x" * (MAX_FRAME_BYTES + 1))
        code, _ = await closed_with(ws)
        assert code == 1009


async def test_a_foreign_page_is_refused_at_the_handshake() -> None:
    async with running_door() as (door, _):
        with pytest.raises(InvalidStatus) as info:
            await connect(door.url, origin="http://evil.example")  # type: ignore[arg-type]
        assert info.value.response.status_code == 403
        # An Origin header, not a socket: the page at Settings' default address and port.
        ws = await opened(door, origin="http://127.0.0.1:8000")  # type: ignore[arg-type]
        await ws.close()


async def _tcp(host: str, port: int, source: str) -> asyncio.StreamWriter:
    _, writer = await asyncio.open_connection(host, port, local_addr=(source, 0))
    return writer


async def test_unauthenticated_connections_are_capped_per_address_and_in_all() -> None:
    limits = DoorLimits(unauthenticated_per_address=4, unauthenticated=8, authenticated=2)
    async with running_door(limits) as (door, _):
        pilot = await opened(door)  # held before the flood
        one = fresh_address()
        a = [await _tcp(HOST, door.port, one) for _ in range(5)]
        await until_async(
            lambda: door.counts.refused_at_accept == 1, 10.0, "the 5th from one address"
        )
        assert door.counts.unauthenticated_total == 4
        two = fresh_address()
        b = [await _tcp(HOST, door.port, two) for _ in range(4)]
        await until_async(lambda: door.counts.unauthenticated_total == 8, 10.0, "a second address")
        # all unauthenticated places taken: a newcomer from a third address is refused ...
        c = await _tcp(HOST, door.port, fresh_address())
        await until_async(lambda: door.counts.refused_at_accept == 2, 10.0, "the overall cap")
        # ... while the held connection goes on: heartbeats, and a stop is run
        await recv_op(pilot, Heartbeat)
        await pilot.send(encode(Stop("hover", "h1", None)))
        assert (await recv_op(pilot, Ack)).accepted
        assert door.counts.authenticated == 1
        for w in (*a, *b, c):
            w.close()
        await pilot.close()


async def test_the_held_connection_keeps_working_through_a_no_token_flood() -> None:
    """16 connections without a token, refreshed every 1.5 s (issue 26, finding 3), from the
    page's own address and from others: the page's standing connection still gets its
    heartbeats and its emergency is run."""
    async with running_door() as (door, vehicle):
        pilot = await opened(door)
        sources = [HOST, fresh_address(), fresh_address()]
        stop_flood = asyncio.Event()

        async def flood() -> None:
            while not stop_flood.is_set():
                held = []
                for i in range(16):
                    with contextlib.suppress(OSError):
                        held.append(await _tcp(HOST, door.port, sources[i % len(sources)]))
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop_flood.wait(), 1.5)
                for w in held:
                    w.close()

        flooding = asyncio.create_task(flood())
        try:
            await until_async(
                lambda: door.counts.refused_at_accept > 0, 10.0, "the flood to hit the caps"
            )
            beats = 0
            deadline = time.monotonic() + 3.2  # two refreshes of the flood
            while time.monotonic() < deadline:
                if isinstance(await recv(pilot), Heartbeat):
                    beats += 1
            assert beats >= 3
            await pilot.send(encode(Stop("emergency", "during-flood", time.time())))
            ack = await recv_op(pilot, Ack)
            assert ack.accepted and vehicle.ran == [("emergency", "during-flood")]
        finally:
            stop_flood.set()
            await flooding
            await pilot.close()


async def test_the_door_over_tls_for_a_page_on_the_lan(tmp_path: Path) -> None:
    host = fresh_address()  # stands for a LAN address
    files = ensure_server_cert(tmp_path / "tls", host)
    assert files.ca is not None
    async with running_door(tls=server_context(files.cert, files.key), host=host) as (door, v):
        assert door.url.startswith(f"wss://{host}:")
        verify_ca = ssl.create_default_context(cafile=str(files.ca))
        ws = await opened(door, ssl=verify_ca)
        await ws.send(encode(Stop("land", "tls-1", None)))
        assert (await recv_op(ws, Ack)).accepted and v.ran == [("land", "tls-1")]
        await ws.close()
        # a TLS handshake that never comes is cut off at the auth deadline too
        reader, writer = await asyncio.open_connection(host, door.port)
        assert await asyncio.wait_for(reader.read(), 10) == b""
        writer.close()
