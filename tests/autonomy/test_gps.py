"""GPS outdoors: the navdata option's whole layout, the simulated receiver, and the vehicle's
``/ardrone/navdata_gps`` (ardrone_autonomy's message, also in ROS 1 form for cbor-raw)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drone.ardrone import at
from drone.ardrone.navdata import (
    GPS_CHANNELS,
    TAG_GPS,
    DroneState,
    Gps,
    Navdata,
    decode_navdata,
    encode_navdata,
)
from drone.control.pid import Setpoint
from drone.lockstep import LockstepRig
from drone.sim.drone import SimConfig, SimDrone
from drone.sim.world import load_world

f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
f64 = st.floats(allow_nan=False, allow_infinity=False)
u32 = st.integers(0, 2**32 - 1)
u8 = st.integers(0, 255)
full_gps = st.builds(
    Gps,
    f64,
    f64,
    f64,
    f64,
    u32,
    zero_validated=u32,
    lat0_deg=f64,
    gps_state=u32,
    x_traj=f32,
    phi_d=f32,
    pdop=f64,
    speed_m_s=f32,
    last_frame_timestamp=u32,
    degree=f32,
    c_n0=f32,
    nbsat=u32,
    channels=st.lists(st.tuples(u8, u8), max_size=GPS_CHANNELS).map(tuple),
    is_gps_plugged=u32,
    firmware_status=u32,
)


@settings(deadline=None)
@given(full_gps)
def test_every_field_of_the_gps_option_survives_the_wire(gps: Gps) -> None:
    nav = Navdata(state=DroneState(0), sequence=7, gps=gps)
    data = encode_navdata(nav)
    assert len(data) == 16 + 216 + 8  # header, the option's 216 bytes, checksum
    assert decode_navdata(data).gps == gps


def test_channels_are_twelve_and_more_are_refused() -> None:
    g = Gps(1.0, 2.0, 3.0, channels=((5, 40),))
    assert len(g.channels) == GPS_CHANNELS and g.channels[1] == (0, 0)
    with pytest.raises(ValueError, match="12 channels"):
        Gps(1.0, 2.0, 3.0, channels=((1, 1),) * 13)


def _gps_sim(**cfg: float) -> SimDrone:
    sim = SimDrone(load_world("outdoor"), start=(10.0, 20.0, 0.0), config=SimConfig(**cfg))  # type: ignore[arg-type]
    sim.receive_navdata_request(b"\x01", 0.0)
    sim.receive_at(at.encode_command(at.Config("general:navdata_demo", "TRUE"), 1), 0.0)
    options = at.Config("general:navdata_options", str(1 << TAG_GPS))
    sim.receive_at(at.encode_command(options, 2), 0.0)
    return sim


def _fixes(sim: SimDrone, seconds: float) -> list[tuple[float, Gps]]:
    out = []
    for _ in range(round(seconds / 0.005)):
        sim.step(0.005)
        pkt = sim.navdata_due(sim.time)
        if pkt is not None:
            gps = decode_navdata(pkt).gps
            assert gps is not None
            out.append((sim.time, gps))
    return out


def test_the_simulated_receiver_gives_5_fixes_a_second_with_its_noise() -> None:
    import pymap3d

    sim = _gps_sim(gps_noise_m=0.5)
    packets = _fixes(sim, 20.0)
    fixes = []
    for _, g in packets:
        if not fixes or fixes[-1] != g:
            fixes.append(g)
    assert len(packets) > 250 and 95 <= len(fixes) <= 105  # 15 Hz navdata, 5 Hz fixes
    o = sim.gps_origin
    assert o is not None
    en = np.array(
        [
            pymap3d.geodetic2enu(
                g.latitude_deg, g.longitude_deg, g.elevation_m, o.lat_deg, o.lon_deg, o.alt_m
            )[:2]
            for g in fixes
        ]
    )
    err = en - np.array([10.0, 20.0])
    assert np.abs(err.mean(axis=0)).max() < 0.15  # no bias
    sd = err.std(axis=0)
    assert sd.min() > 0.4 and sd.max() < 0.6
    g = fixes[-1]
    assert g.data_available == 1 and g.is_gps_plugged == 1 and g.nbsat == 9
    assert g.hdop > 0 and g.vdop > 0 and g.pdop == pytest.approx(math.hypot(g.hdop, g.vdop))
    assert sum(1 for sat, cn0 in g.channels if sat) == 9 and g.c_n0 > 30


def test_ground_speed_and_course_follow_the_drone() -> None:
    rig = LockstepRig(load_world("outdoor"), seed=2, camera=False)
    seen: list[tuple[Gps, float, float]] = []

    def on_nav(nav: Navdata, now: float) -> None:
        tr = rig.sim.truth
        if nav.gps is not None and (not seen or seen[-1][0] != nav.gps):
            seen.append((nav.gps, math.hypot(tr.vx, tr.vy), math.atan2(tr.vx, tr.vy)))

    rig.vehicle.add_navdata_listener(on_nav)
    assert rig.wait_link() and rig.takeoff_all()
    rig.vehicle.set_setpoint(Setpoint(30.0, 30.0, 2.0, math.pi / 4))  # north-east
    rig.run(8.0)
    moving = [(g, v, c) for g, v, c in seen[-10:]]
    assert all(v > 1.0 for _, v, _ in moving)
    for g, v, course in moving:
        assert g.speed_m_s == pytest.approx(v, rel=1e-4)
        assert g.degree == pytest.approx(math.degrees(course) % 360.0, abs=0.01)
    assert all(40.0 < g.degree < 50.0 for g, _, _ in moving)


def test_the_vehicle_publishes_navdata_gps_per_fix_with_ardrone_autonomy_fields() -> None:
    import pymap3d

    from server.graph import Graph
    from server.nodes.vehicle_node import NAVDATA_GPS, VehicleNode
    from tests.autonomy.flight import Flight

    world = load_world("outdoor")
    f = Flight.make(world, seed=4, camera=False)
    g = Graph()
    clock = f.rig.clock.now
    node = VehicleNode(g, f.rig.vehicle, f.tm, "uav2", "/uav2", clock=clock, stamp=clock)
    got: list[dict[str, object]] = []
    g.subscribe("/uav2/ardrone/navdata_gps", got.append)
    assert g.topic_type("/uav2/ardrone/navdata_gps") == NAVDATA_GPS
    f.submit({"action": "takeoff"}, {"action": "goto", "waypoint": 2})
    assert f.run_until_idle(60.0)
    seconds = f.rig.clock.now()
    assert 4.5 < len(got) / seconds < 5.5  # one message per fix, 5 Hz
    last = got[-1]
    assert (last["tag"], last["size"]) == (27, 216)
    assert last["data_available"] == 1 and last["is_gps_plugged"] is True and last["nbsat"] == 9
    assert len(last["channels"]) == 12 and last["channels"][0]["sat"] == 1  # type: ignore[arg-type,index]
    o = world.gps_origin
    assert o is not None
    e, n, _ = pymap3d.geodetic2enu(
        last["latitude"], last["longitude"], last["elevation"], o.lat_deg, o.lon_deg, o.alt_m
    )
    tr = f.rig.sim.truth
    assert math.hypot(e - tr.x, n - tr.y) < 0.5  # exact fixes, at most 0.2 s old
    node.close()
    assert g.publishers("/uav2/ardrone/navdata_gps") == []


def test_indoors_there_is_no_navdata_gps() -> None:
    from server.graph import Graph
    from server.nodes.vehicle_node import VehicleNode
    from server.vehicles.host import shared_topics
    from tests.autonomy.flight import Flight

    f = Flight.make(load_world("indoor"), seed=4, camera=False)
    g = Graph()
    VehicleNode(g, f.rig.vehicle, f.tm, "uav1", "", clock=f.rig.clock.now)
    assert "/ardrone/navdata_gps" not in g.topics()
    assert "/ardrone/navdata_gps" not in {t.name for t in shared_topics("uav1", "")}
    topics = shared_topics("uav2", "/uav2", gps=True)
    assert {t.name: t.type for t in topics}["/uav2/ardrone/navdata_gps"] == (
        "ardrone_autonomy/navdata_gps"
    )


def test_navdata_gps_has_a_ros1_definition_and_serialisation() -> None:
    from server.nodes.vehicle_node import navdata_gps_message
    from server.ros1 import codec_for
    from server.rosbridge.rosapi import full_text, typedefs

    text = full_text("ardrone_autonomy/navdata_gps")
    assert text.startswith("std_msgs/Header header\nuint16 tag\nuint16 size\nfloat64 latitude")
    assert "ardrone_autonomy/navdata_gps_channel[12] channels" in text
    assert "MSG: ardrone_autonomy/navdata_gps_channel\nuint8 sat\nuint8 c_n0" in text
    top = typedefs("ardrone_autonomy/navdata_gps")[0]
    assert top["fieldarraylen"][top["fieldnames"].index("channels")] == 12
    gps = Gps(36.3, 127.3, 61.0, 0.9, 1, nbsat=3, channels=((1, 40), (2, 39), (3, 38)))
    msg = navdata_gps_message(gps, 1_700_000_000.25)
    codec = codec_for("ardrone_autonomy/navdata_gps")
    data = codec.encode(msg)
    # Header (seq, stamp, frame id "ardrone_base_link"), tag and size, then the option's 212
    # bytes less 3 for each of its three int32 booleans, one byte each in ROS 1
    assert len(data) == (4 + 8 + 4 + 17) + 4 + 212 - 3 * 3
    back = codec.decode(data)
    assert back["latitude"] == 36.3 and back["nbsat"] == 3
    assert back["channels"][2] == {"sat": 3, "c_n0": 38} and len(back["channels"]) == 12
