"""What bench/fuzz.py's MAVLink target found (issue 14's fuzz campaign), each now a test.

Frames with valid CRCs (anyone on the link can compute one) whose fields no autopilot sends:
a MISSION_ACK result the dialect does not name raised KeyError out of ``receive``; an infinite
ATTITUDE yaw raised ValueError out of ``MavlinkVehicle.snapshot`` (``math.remainder``), a NaN
NAV_DLL_ACT did the same in the failsafe text (``int(nan)``), and NaN velocities or positions
reached the snapshot the fleet reads.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import pytest

from drone.control.clock import VirtualClock
from drone.mavlink.codec import Codec, mav
from drone.mavlink.gcs.events import MissionResult
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.vehicle import MavlinkVehicle

WORLD = SimpleNamespace(gps_origin=SimpleNamespace(lat_deg=47.397, lon_deg=8.545, alt_m=488.0))
NAN, INF = math.nan, math.inf


def _linked(**kw: Any) -> tuple[GcsProtocol, MavlinkVehicle, Codec]:
    vehicle = Codec(1, 1)
    p = GcsProtocol(request_streams=False, **kw)
    v = MavlinkVehicle("uav1", WORLD, p, clock=VirtualClock(0.0))
    hb = vehicle.mav.heartbeat_encode(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, mav.MAV_MODE_FLAG_SAFETY_ARMED, 0, 4
    )
    p.receive(vehicle.encode(hb), 0.0)
    for event in p.events():
        v.on_event(event)
    return p, v, vehicle


def _finite_snapshot(v: MavlinkVehicle) -> None:
    s = v.snapshot()
    for name in ("battery_pct", "altitude_m", "x", "y", "z", "yaw_rad", "vx", "vy", "vz"):
        assert math.isfinite(getattr(s, name)), name
    assert isinstance(s.extra["failsafe"], str)


def test_a_mission_ack_with_an_unknown_result_ends_the_upload() -> None:
    p, _, vehicle = _linked()
    p.upload_mission([(47.3971, 8.5451, 5.0)], 0.1)
    p.receive(vehicle.encode(vehicle.mav.mission_ack_encode(255, 190, 190)), 0.2)
    results = [e for e in p.events() if isinstance(e, MissionResult)]
    assert results == [MissionResult(False, 1, "result 190")]


Encode = Callable[[Any], Any]
IMPLAUSIBLE: list[tuple[str, Encode]] = [
    ("attitude yaw inf", lambda m: m.attitude_encode(1, 0.0, 0.0, INF, 0.0, 0.0, 0.0)),
    ("attitude roll nan", lambda m: m.attitude_encode(1, NAN, 0.0, 0.0, 0.0, 0.0, 0.0)),
    (
        "local velocity nan",
        lambda m: m.local_position_ned_encode(1, 1.0, 2.0, -3.0, NAN, 0.0, 0.0),
    ),
    (
        "local position -inf",
        lambda m: m.local_position_ned_encode(1, 1.0, -INF, -3.0, 0.0, 0.0, 0.0),
    ),
    (
        "global position off the globe",
        lambda m: m.global_position_int_encode(
            1, 2_000_000_000, 85450000, 490500, 2500, 0, 0, 0, 0
        ),
    ),
    (
        "home local nan",
        lambda m: m.home_position_encode(
            473960000, 85440000, 488000, NAN, 0.0, 0.0, [1, 0, 0, 0], 0, 0, 0
        ),
    ),
    (
        "home off the globe",
        lambda m: m.home_position_encode(
            473960000, -1_900_000_000, 488000, 0.0, 0.0, 0.0, [1, 0, 0, 0], 0, 0, 0
        ),
    ),
    ("NAV_DLL_ACT nan", lambda m: m.param_value_encode(b"NAV_DLL_ACT", NAN, 6, 900, 1)),
    ("COM_DL_LOSS_T inf", lambda m: m.param_value_encode(b"COM_DL_LOSS_T", INF, 9, 900, 2)),
]


@pytest.mark.parametrize("encode", [e for _, e in IMPLAUSIBLE], ids=[n for n, _ in IMPLAUSIBLE])
def test_non_finite_or_off_the_globe_telemetry_is_dropped_and_counted(encode: Encode) -> None:
    p, v, vehicle = _linked()
    before = p.telemetry
    p.receive(vehicle.encode(encode(vehicle.mav)), 0.1)
    assert p.codec.rejected["implausible"] == 1
    assert p.telemetry == before and p.params == {}
    _finite_snapshot(v)


def test_plausible_telemetry_still_arrives() -> None:
    p, v, vehicle = _linked()
    m = vehicle.mav
    frames = [
        m.attitude_encode(1, 0.1, -0.1, 1.0, 0.0, 0.0, 0.0),
        m.local_position_ned_encode(1, 1.0, 2.0, -3.0, 0.5, 0.0, 0.0),
        m.global_position_int_encode(1, -899_999_999, 1_799_999_999, 0, 0, 0, 0, 0, 0),
        m.param_value_encode(b"NAV_DLL_ACT", 2.0, 6, 900, 1),
    ]
    p.receive(b"".join(vehicle.encode(f) for f in frames), 0.1)
    assert p.codec.rejected["implausible"] == 0
    assert p.telemetry.heading_rad == pytest.approx(1.0)
    assert p.telemetry.local_ned == (1.0, 2.0, -3.0)
    assert p.telemetry.lat_deg == pytest.approx(-89.9999999)
    assert p.params == {"NAV_DLL_ACT": 2.0}
    assert "return to launch" in p.failsafe_text()
    _finite_snapshot(v)
