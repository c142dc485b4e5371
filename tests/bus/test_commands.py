"""Commands on the bus, sans-I/O: the codec (every input decodes or is refused with a reason)
and the vehicle's pilot lease (stops from any pilot, motion from its holder only)."""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drone.bus.commands import (
    OPS,
    Command,
    CommandReply,
    decode_command,
    decode_reply,
    encode_command,
    encode_reply,
    id_of,
)
from drone.bus.errors import PayloadError
from drone.bus.lease import LEASE_IDLE_S, VehicleLease
from drone.bus.payloads import Status, decode_status, encode


def command(op: str = "direct", console: str = "a", pilot: str = "pilot", **args: Any) -> Command:
    if op == "direct" and "action" not in args:
        args["action"] = "takeoff"
    return Command(id="c1", op=op, args=args, console=console, pilot=pilot)  # type: ignore[arg-type]


json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3)
    ),
    max_leaves=8,
)
commands = st.builds(
    Command,
    id=st.text(min_size=1, max_size=96),
    op=st.sampled_from(["telemetry", "truth", "fault", "lease"]),
    args=st.dictionaries(st.text(max_size=8), json_values, max_size=4),
    issued=st.none() | st.floats(allow_nan=False, allow_infinity=False),
    console=st.text(min_size=1, max_size=20),
    pilot=st.text(min_size=1, max_size=20),
)


@given(commands)
def test_a_command_round_trips(cmd: Command) -> None:
    assert decode_command(encode_command(cmd)) == cmd


@given(st.binary(max_size=300))
def test_any_bytes_decode_or_are_refused_with_a_reason(data: bytes) -> None:
    try:
        decode_command(data)
    except PayloadError as exc:
        assert str(exc).startswith("command")


@given(
    st.dictionaries(
        st.sampled_from(["v", "id", "op", "args", "issued", "console", "pilot", "x"]), json_values
    )
)
def test_any_json_object_decodes_or_is_refused_with_a_reason(raw: dict[str, Any]) -> None:
    try:
        cmd = decode_command(json.dumps(raw).encode())
    except PayloadError as exc:
        assert str(exc).startswith("command ")
    else:
        assert cmd.op in OPS and cmd.id == raw["id"]


@given(st.binary(max_size=200))
def test_the_id_of_anything_is_a_string(data: bytes) -> None:
    assert isinstance(id_of(data), str)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"\xff{", "not JSON"),
        (b"[1, 2]", "command payload"),
        (b'{"id": "1", "op": "fly", "console": "a", "pilot": "p"}', "unknown op 'fly'"),
        (b'{"id": "1", "op": "direct", "console": "a", "pilot": "p"}', "args.action"),
        (
            b'{"id": "1", "op": "direct", "args": {"action": "barrel-roll"}, "console": "a", '
            b'"pilot": "p"}',
            "'barrel-roll' is not one of",
        ),
        (b'{"id": "1", "op": "utterance", "console": "a", "pilot": "p"}', "needs its text"),
        (b'{"id": "1", "op": "telemetry", "pilot": "p"}', "command console: Field required"),
        (b'{"v": 2, "id": "1", "op": "telemetry", "console": "a", "pilot": "p"}', "command v"),
        (
            b'{"id": "1", "op": "telemetry", "console": "a", "pilot": "p", "issued": 1e999}',
            "command issued",
        ),
        (b"{" * 100_000, "bytes (at most"),
    ],
)
def test_malformed_commands_are_refused_with_a_clear_reason(payload: bytes, reason: str) -> None:
    with pytest.raises(PayloadError, match=reason.replace("(", r"\(").replace("[", r"\[")):
        decode_command(payload)


def test_stops_and_holders() -> None:
    assert command(action="land").is_stop and command(action="emergency").is_stop
    assert not command(action="takeoff").is_stop and not command("telemetry").is_stop
    assert command(console="west", pilot="rest").holder == "rest@west"


@given(st.booleans(), st.text(max_size=30), st.dictionaries(st.text(max_size=5), json_values))
def test_a_reply_round_trips(accepted: bool, reason: str, result: dict[str, Any]) -> None:
    reply = CommandReply(id="c", drone="uav1", accepted=accepted, reason=reason, result=result)
    assert decode_reply(encode_reply(reply)) == reply


def test_status_decodes_and_refuses() -> None:
    status = Status(drone="uav1", stamp=1.0, mode="LANDED", lease="rest@a", alarms=["battery low"])
    assert decode_status(encode(status)) == status
    with pytest.raises(PayloadError, match="status mode"):
        decode_status(b'{"drone": "uav1", "stamp": 1}')


# ---------------------------------------------------------------------- the lease


def test_motion_takes_the_free_lease_and_others_are_refused() -> None:
    lease = VehicleLease()
    assert lease.judge(command(console="a"), 0.0).allowed
    assert lease.current(1.0) == "pilot@a"
    refused = lease.judge(command(console="b"), 1.0)
    assert not refused.allowed and "held by pilot@a" in refused.reason
    assert lease.judge(command(console="a", action="reset"), 2.0).allowed
    assert lease.judge(command(console="a", pilot="other", action="reset"), 3.0).allowed
    assert lease.current(3.0) == "other@a"  # its console's own lease chose the pilot


@pytest.mark.parametrize("action", ["land", "hover", "emergency"])
def test_any_pilot_stops_whoever_holds_the_lease(action: str) -> None:
    lease = VehicleLease()
    lease.judge(command(console="a"), 0.0)
    assert lease.judge(command(console="b", action=action), 1.0).allowed
    assert lease.current(1.0) == "pilot@a"  # a stop takes nothing


def test_reads_need_no_lease_and_an_utterance_is_judged_by_what_it_asks() -> None:
    lease = VehicleLease(actions_of=lambda text: {"land"} if "land" in text else {"takeoff"})
    lease.judge(command(console="a"), 0.0)
    assert lease.judge(command("telemetry", console="b"), 1.0).allowed
    assert lease.judge(command("utterance", console="b", text="land now"), 1.0).allowed
    assert not lease.judge(command("utterance", console="b", text="take off"), 1.0).allowed


def test_a_lease_lapses_when_unused_and_can_be_taken_over_or_released() -> None:
    lease = VehicleLease()
    lease.judge(command(console="a"), 0.0)
    assert lease.judge(command(console="b"), LEASE_IDLE_S + 1).allowed
    assert lease.current(LEASE_IDLE_S + 1) == "pilot@b"
    assert lease.judge(command(console="a", take_over=True), LEASE_IDLE_S + 2).allowed
    assert not lease.judge(
        command("lease", console="b", action="acquire"), LEASE_IDLE_S + 3
    ).allowed
    assert lease.judge(command("lease", console="a", action="release"), LEASE_IDLE_S + 3).allowed
    assert lease.current(LEASE_IDLE_S + 3) is None
    assert not lease.judge(command("lease", action="steal"), 0).allowed
