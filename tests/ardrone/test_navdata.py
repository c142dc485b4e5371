"""Navdata codec: golden bytes, pyardrone's parser as an independent reader, errors, Hypothesis."""

from __future__ import annotations

import contextlib
import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drone.ardrone.errors import (
    NavdataChecksumError,
    NavdataError,
    NavdataMagicError,
    NavdataOptionSizeError,
    NavdataTruncatedError,
)
from drone.ardrone.navdata import (
    CtrlState,
    Demo,
    DroneState,
    Gps,
    Navdata,
    PressureRaw,
    decode_navdata,
    encode_navdata,
)

# Bootstrap packet, state = bit 11, sequence 3; checksum 0x1c5 = sum of the 16 header bytes
# (0x88+0x77+0x66+0x55+0x08+0x03), worked out by hand from Developer Guide §7.1.
BOOTSTRAP = bytes.fromhex("88776655000800000300000000000000ffff0800c5010000")


def test_bootstrap_golden_bytes() -> None:
    nav = Navdata(state=DroneState.NAVDATA_BOOTSTRAP, sequence=3)
    assert encode_navdata(nav) == BOOTSTRAP
    decoded = decode_navdata(BOOTSTRAP)
    assert decoded == nav
    assert decoded.bootstrap and decoded.demo is None and decoded.checksum == 0x1C5


def test_demo_option_layout_matches_navdata_demo_t() -> None:
    demo = Demo(
        ctrl_state=(CtrlState.HOVERING << 16) | 2,
        battery_pct=87,
        theta_mdeg=1500.0,
        phi_mdeg=-2500.0,
        psi_mdeg=90000.0,
        altitude_mm=812,
        vx_mm_s=100.0,
        vy_mm_s=-200.0,
        vz_mm_s=25.0,
        num_frames=42,
    )
    state = DroneState.FLY | DroneState.NAVDATA_DEMO
    data = encode_navdata(Navdata(state=state, sequence=9, demo=demo))
    assert len(data) == 16 + 148 + 8
    assert struct.unpack_from("<HH", data, 16) == (0, 148)
    assert struct.unpack_from("<II", data, 20) == ((4 << 16) | 2, 87)
    assert struct.unpack_from("<fffi", data, 28) == (1500.0, -2500.0, 90000.0, 812)
    assert struct.unpack_from("<fffI", data, 44) == (100.0, -200.0, 25.0, 42)
    assert data[60:164] == bytes(104)  # deprecated detection/drone camera fields
    assert struct.unpack_from("<HHI", data, 164) == (0xFFFF, 8, sum(data[:164]))
    nav = decode_navdata(data)
    assert nav.demo == demo and nav.demo.major is CtrlState.HOVERING and nav.demo.minor == 2


def test_pyardrone_reads_our_packets() -> None:
    """A third-party ctypes reader of navdata_common.h agrees with our encoder."""
    from pyardrone.navdata import NavData
    from pyardrone.navdata.states import DroneState as PyState

    demo = Demo(ctrl_state=3 << 16, battery_pct=55, psi_mdeg=-45000.0, altitude_mm=1234)
    data = encode_navdata(Navdata(DroneState.FLY | DroneState.COM_WATCHDOG, 77, 0, demo))
    theirs = NavData(data)
    assert theirs.metadata.sequence_number == 77
    assert PyState(theirs.metadata.state).fly_mask
    assert theirs.demo.vbat_flying_percentage == 55
    assert theirs.demo.altitude == 1234 and theirs.demo.psi == -45000.0
    assert theirs.cks.value == sum(data[:-8])


def test_to_body_follows_ardrone_autonomy_signs() -> None:
    demo = Demo(
        ctrl_state=CtrlState.FLYING << 16,
        battery_pct=50,
        theta_mdeg=10000.0,  # nose up 10°
        phi_mdeg=5000.0,  # right wing down 5°
        psi_mdeg=30000.0,  # 30° clockwise
        altitude_mm=1500,
        vx_mm_s=300.0,
        vy_mm_s=200.0,  # right
        vz_mm_s=100.0,  # down
    )
    body = Navdata(DroneState.FLY, 1, demo=demo).to_body()
    assert body.roll_rad == pytest.approx(math.radians(5))
    assert body.pitch_rad == pytest.approx(-math.radians(10))  # REP 103: nose up is negative
    assert body.yaw_rad == pytest.approx(-math.radians(30))  # CCW positive
    assert (body.vx_m_s, body.vy_m_s, body.vz_m_s) == pytest.approx((0.3, -0.2, -0.1))
    assert body.altitude_m == 1.5 and body.flying and body.ctrl_state is CtrlState.FLYING
    with pytest.raises(ValueError, match="no demo"):
        Navdata(DroneState.NAVDATA_BOOTSTRAP, 1).to_body()


def test_gps_option_only_when_given_and_unknown_options_are_skipped() -> None:
    plain = encode_navdata(Navdata(DroneState(0), 1, demo=Demo()))
    assert b"\x1b\x00\xd8\x00" not in plain  # tag 27, size 216
    nav = Navdata(
        DroneState(0),
        2,
        demo=Demo(),
        gps=Gps(36.367164, 127.363472, 60.0),
        unknown=((1, b"\x01\x02\x03\x04"), (300, b"")),
    )
    data = encode_navdata(nav)
    assert len(data) == 16 + 148 + 216 + 8 + 4 + 8
    assert decode_navdata(data) == nav


def _with_checksum(body: bytes) -> bytes:
    return body + struct.pack("<HHI", 0xFFFF, 8, sum(body) & 0xFFFFFFFF)


@pytest.mark.parametrize(
    ("data", "error"),
    [
        (b"", NavdataTruncatedError),
        (b"\x88\x77", NavdataTruncatedError),
        (BOOTSTRAP[:12], NavdataTruncatedError),
        (b"\x00" * 24, NavdataMagicError),
        (BOOTSTRAP[:-1], NavdataTruncatedError),  # checksum option cut
        (BOOTSTRAP[:16], NavdataChecksumError),  # no checksum option at all
        (BOOTSTRAP[:-4] + struct.pack("<I", 0x1C6), NavdataChecksumError),  # wrong value
        (BOOTSTRAP[:16] + struct.pack("<HH", 5, 2), NavdataOptionSizeError),  # size < 4
        (BOOTSTRAP[:16] + struct.pack("<HH", 5, 100), NavdataTruncatedError),  # past the end
        (
            _with_checksum(BOOTSTRAP[:16] + struct.pack("<HH", 0, 8) + bytes(4)),
            NavdataOptionSizeError,
        ),
        (BOOTSTRAP[:16] + struct.pack("<HHII", 0xFFFF, 12, 0, 0), NavdataOptionSizeError),
    ],
)
def test_bad_packets_raise_the_documented_error(data: bytes, error: type[NavdataError]) -> None:
    with pytest.raises(error):
        decode_navdata(data)


f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
u32 = st.integers(0, 2**32 - 1)
demos = st.builds(
    Demo, u32, u32, f32, f32, f32, st.integers(-(2**31), 2**31 - 1), f32, f32, f32, u32
)
f64 = st.floats(allow_nan=False, allow_infinity=False)
gpss = st.builds(Gps, f64, f64, f64, f64, u32)
i32 = st.integers(-(2**31), 2**31 - 1)
pressures = st.builds(PressureRaw, i32, st.integers(-(2**15), 2**15 - 1), i32, i32)
unknowns = st.lists(
    st.tuples(
        st.integers(1, 0xFFFE).filter(lambda t: t not in (0, 21, 27)), st.binary(max_size=40)
    ),
    max_size=3,
).map(tuple)
packets = st.builds(
    Navdata,
    st.builds(DroneState, u32),
    u32,
    u32,
    st.none() | demos,
    st.none() | gpss,
    unknowns,
    pressure=st.none() | pressures,
)


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(packets)
def test_encode_then_decode_is_identity(nav: Navdata) -> None:
    assert decode_navdata(encode_navdata(nav)) == nav


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(st.binary(max_size=400))
def test_arbitrary_bytes_decode_or_raise_navdata_error(data: bytes) -> None:
    with contextlib.suppress(NavdataError):
        decode_navdata(data)


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(st.binary(max_size=400))
def test_arbitrary_options_after_a_valid_header(tail: bytes) -> None:
    data = BOOTSTRAP[:16] + tail
    try:
        nav = decode_navdata(data)
    except NavdataError:
        return
    assert nav.sequence == 3


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(packets, st.integers(0, 10_000), st.integers(1, 255))
def test_any_corruption_is_detected_or_harmless(nav: Navdata, pos: int, flip: int) -> None:
    data = bytearray(encode_navdata(nav))
    data[pos % len(data)] ^= flip
    with contextlib.suppress(NavdataError):
        decode_navdata(bytes(data))


def test_ros_fields_match_the_graph_message_type() -> None:
    from drone.ardrone.navdata import ros_navdata_fields

    demo = Demo(CtrlState.HOVERING << 16, 77, 2000.0, -1000.0, 90000.0, 800, 10.0, 20.0, 30.0)
    fields = ros_navdata_fields(Navdata(DroneState.FLY, 5, demo=demo), tm_us=1.5e6)
    assert fields["state"] == 4 and fields["batteryPercent"] == 77.0 and fields["altd"] == 800
    assert (fields["rotX"], fields["rotY"], fields["rotZ"]) == (-1.0, -2.0, -90.0)
    assert (fields["vx"], fields["vy"], fields["vz"]) == (10.0, -20.0, -30.0)
    assert fields["tm"] == 1.5e6
    try:
        from server.msgs import default_message
    except ImportError:
        return
    expected = set(default_message("ardrone_autonomy/Navdata")) - {"header"}
    assert set(fields) == expected
