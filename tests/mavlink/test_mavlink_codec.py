"""MAVLink 2 framing, modes and frames: golden values, Hypothesis garbage and round trips."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v10 import common as v1

from drone.mavlink.codec import Codec, mav
from drone.mavlink.driver import parse_connection
from drone.mavlink.errors import ConnectionStringError
from drone.mavlink.geo import Origin, enu_to_ned, yaw_enu_to_ned, yaw_ned_to_enu
from drone.mavlink.modes import custom_mode, intent_mode, mode_name, px4_custom_mode

KEY = bytes(range(32))


def _heartbeat(codec: Codec) -> bytes:
    return codec.encode(codec.mav.heartbeat_encode(2, 12, 0, 0, 4))


def test_px4_custom_modes_match_px4_custom_mode_h() -> None:
    # main << 16 | sub << 24 (px4_custom_mode.h)
    assert px4_custom_mode("POSCTL") == 3 << 16
    assert px4_custom_mode("AUTO.LOITER") == (4 << 16) | (3 << 24) == 0x03040000
    assert px4_custom_mode("AUTO.RTL") == (4 << 16) | (5 << 24)
    assert px4_custom_mode("OFFBOARD") == 6 << 16
    for name in ("AUTO.TAKEOFF", "AUTO.MISSION", "AUTO.LAND", "OFFBOARD", "POSCTL"):
        assert mode_name(mav.MAV_AUTOPILOT_PX4, px4_custom_mode(name)) == name
    assert mode_name(mav.MAV_AUTOPILOT_PX4, 99 << 16) == "PX4(99.0)"


def test_arducopter_modes_and_intents() -> None:
    apm = mav.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert custom_mode(apm, "GUIDED") == 4 and custom_mode(apm, "RTL") == 6
    assert mode_name(apm, 5) == "LOITER"
    assert intent_mode(apm, "hold") == "LOITER" and intent_mode(apm, "offboard") == "GUIDED"
    assert intent_mode(mav.MAV_AUTOPILOT_PX4, "rtl") == "AUTO.RTL"


def test_frames_enu_ned() -> None:
    assert enu_to_ned(1.0, 2.0, 3.0) == (2.0, 1.0, -3.0)
    assert math.isclose(yaw_enu_to_ned(math.pi / 2), 0.0, abs_tol=1e-12)  # north
    assert math.isclose(yaw_enu_to_ned(0.0), math.pi / 2)  # east is 90° clockwise from north
    for yaw in (-3.0, -1.0, 0.0, 0.5, 3.0):
        assert math.isclose(yaw_ned_to_enu(yaw_enu_to_ned(yaw)), yaw, abs_tol=1e-12)
    o = Origin(36.367164, 127.363472, 60.0)
    x, y, z = o.to_map(*o.to_geo(15.0, -15.0, 2.5))
    assert math.dist((x, y, z), (15.0, -15.0, 2.5)) < 1e-6
    import pymap3d  # the exact conversion the world loader uses

    for p in ((60.0, 60.0, 0.0), (-60.0, 25.0, 40.0), (15.0, -15.0, 2.5)):
        lat, lon, alt = pymap3d.enu2geodetic(*p, o.lat_deg, o.lon_deg, o.alt_m)
        assert math.dist(o.to_map(float(lat), float(lon), float(alt)), p) < 1e-3


def test_bad_crc_mavlink1_and_garbage_are_counted_not_raised() -> None:
    a, b = Codec(1, 1), Codec(255, 190)
    good = _heartbeat(a)
    bad = bytearray(good)
    bad[-1] ^= 0xFF
    m1 = v1.MAVLink(None, 1, 1)
    frame_v1 = m1.heartbeat_encode(2, 12, 0, 0, 4).pack(m1)
    got = b.feed(b"\x00junk" + bytes(bad) + frame_v1 + good)
    assert [m.get_type() for m in got] == ["HEARTBEAT"]
    assert b.rejected["bad_crc"] == 1 and b.rejected["mavlink1"] == 1
    assert b.rejected["garbage"] >= 1


def test_signing_accepts_the_key_and_rejects_others() -> None:
    signer = Codec(1, 1, signing_key=KEY)
    frame = _heartbeat(signer)
    assert len(frame) == len(_heartbeat(Codec(1, 1))) + 13  # 13-byte signature block
    assert len(Codec(255, 190, signing_key=KEY).feed(frame)) == 1
    wrong = Codec(255, 190, signing_key=bytes(32))
    assert wrong.feed(frame) == [] and wrong.rejected["bad_signature"] == 1
    strict = Codec(255, 190, signing_key=KEY)
    assert strict.feed(_heartbeat(Codec(1, 1))) == []  # unsigned on a signed link


def test_a_forged_frame_from_the_future_does_not_silence_a_signed_link() -> None:
    """pymavlink 2.4.50 stored a frame's timestamp before checking its signature: one frame
    signed with a wrong key and a far-future timestamp made every genuine frame after it
    "old", so anyone on the link could cut a signed vehicle off. Replays stay refused."""
    t0 = 3_000_000_000
    vehicle = Codec(1, 1, signing_key=KEY, initial_timestamp=t0)
    forger = Codec(1, 1, signing_key=bytes(32), initial_timestamp=t0 + 10**9)
    gcs = Codec(255, 190, signing_key=KEY, initial_timestamp=t0)
    first = _heartbeat(vehicle)
    assert len(gcs.feed(first)) == 1
    assert gcs.feed(_heartbeat(forger)) == []
    assert len(gcs.feed(_heartbeat(vehicle) + _heartbeat(vehicle))) == 2
    assert gcs.feed(first) == []  # a replay of an older genuine frame
    assert gcs.rejected["bad_signature"] == 2


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    c = Codec(255, 190)
    for msg in c.feed(data):
        assert msg.get_msgbuf()[0] == 0xFD


@settings(max_examples=100, deadline=None)
@given(
    st.integers(0, 65535),
    st.sampled_from([mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_DO_SET_MODE, 400]),
    st.lists(st.floats(-1e6, 1e6, allow_nan=False, width=32), min_size=7, max_size=7),
    st.integers(0, 40),
)
def test_command_long_round_trip(_: int, command: int, params: list[float], split: int) -> None:
    a, b = Codec(255, 190), Codec(1, 1)
    frame = a.encode(a.mav.command_long_encode(1, 1, command, 0, *params))
    got = b.feed(frame[:split]) + b.feed(frame[split:])
    assert len(got) == 1
    assert got[0].command == command
    assert [got[0].param1, got[0].param7] == [params[0], params[6]]


def test_connection_strings_as_mavutil_writes_them() -> None:
    assert str(parse_connection("tcp:10.0.0.5:5760")) == "tcp:10.0.0.5:5760"
    assert parse_connection("udpin:0.0.0.0:14550").kind == "udpin"
    assert parse_connection("udp:0.0.0.0:14550").kind == "udpin"  # MAVProxy's udp: listens
    assert parse_connection("udpout:192.168.1.7:14550").kind == "udpout"
    serial = parse_connection("/dev/ttyUSB0,57600")
    assert (serial.kind, serial.host, serial.port) == ("serial", "/dev/ttyUSB0", 57600)
    for bad in ("192.168.1.1", "sim", "tcp:host", "tcp:host:99999", "ftp:a:1", "tcp::5760"):
        try:
            parse_connection(bad)
        except ConnectionStringError as exc:
            assert bad in str(exc) or "port" in str(exc)
        else:
            raise AssertionError(f"{bad!r} parsed")


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=400))
def test_protocol_and_autopilot_survive_arbitrary_bytes(data: bytes) -> None:
    from drone.mavlink.gcs.protocol import GcsProtocol
    from drone.mavlink.sim.autopilot import SimAutopilot

    p = GcsProtocol()
    p.receive(data, 0.0)
    p.tick(0.1)
    ap = SimAutopilot(None)
    ap.receive("x", data)
    ap.step(0.02)
    assert not p.connected


_ANY_FLOAT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32), st.sampled_from([0.0, 1.0, -1.0])
)


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from([16, 20, 21, 22, 176, 178, 185, 192, 300, 400, 511, 512, 520, 31000, 0]),
    st.lists(_ANY_FLOAT, min_size=7, max_size=7),
    st.booleans(),
)
def test_autopilot_answers_every_command_once_whatever_its_params(
    command: int, params: list[float], as_int: bool
) -> None:
    from drone.mavlink.sim.autopilot import SimAutopilot

    ap = SimAutopilot(None)
    gcs = Codec(255, 190)
    if as_int:
        x = int(params[4]) if math.isfinite(params[4]) and abs(params[4]) < 2**31 else 0
        y = int(params[5]) if math.isfinite(params[5]) and abs(params[5]) < 2**31 else 0
        msg = gcs.mav.command_int_encode(1, 1, 0, command, 0, 0, *params[:4], x, y, params[6])
    else:
        msg = gcs.mav.command_long_encode(1, 1, command, 0, *params)
    ap.receive("gcs", gcs.encode(msg))
    for _ in range(5):
        ap.step(0.02)
    acks = [m for m in gcs.feed(ap.drain("gcs")) if m.get_type() == "COMMAND_ACK"]
    assert [a.command for a in acks] == [command]
    assert all(math.isfinite(v) for v in (ap.physics.body.x, ap.physics.body.y, ap.physics.body.z))
