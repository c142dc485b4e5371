"""SimDrone on the wire (bytes in, bytes out) and through InMemoryLink with the real driver core."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drone.ardrone import at
from drone.ardrone.navdata import TAG_GPS, CtrlState, DroneState, decode_navdata
from drone.ardrone.protocol import DriverProtocol, HandshakeDone, LinkLost, LinkRestored
from drone.sim.drone import SimConfig, SimDrone
from drone.sim.errors import FaultError, SimConfigError
from drone.sim.link import InMemoryLink

DT = 0.01


def wire(*commands: at.ATCommand, first: int = 1) -> bytes:
    enc = at.ATEncoder(first_seq=first)
    (datagram,) = enc.pack(commands)
    return datagram


def collect(sim: SimDrone, seconds: float) -> list[bytes]:
    out = []
    for _ in range(round(seconds / DT)):
        sim.step(DT)
        pkt = sim.navdata_due(sim.time)
        if pkt is not None:
            out.append(pkt)
    return out


def test_bootstrap_then_demo_at_15_hz_then_full_at_200_hz() -> None:
    sim = SimDrone(seed=3)
    assert sim.navdata_due(0.0) is None  # nobody asked yet
    sim.receive_navdata_request(b"\x01\x00\x00\x00", 0.0)
    boot = [decode_navdata(p) for p in collect(sim, 1.0)]
    assert 14 <= len(boot) <= 16
    assert all(n.bootstrap and n.demo is None for n in boot)
    assert [n.sequence for n in boot] == list(range(1, len(boot) + 1))
    sim.receive_at(wire(at.Config("general:navdata_demo", "TRUE")), sim.time)
    first = decode_navdata(collect(sim, 0.1)[0])
    assert first.state & DroneState.COMMAND and first.state & DroneState.NAVDATA_DEMO
    sim.receive_at(wire(at.Ctrl(5, 0), first=2), sim.time)
    demo = [decode_navdata(p) for p in collect(sim, 2.0)]
    assert 29 <= len(demo) <= 31
    assert all(n.demo is not None and not n.state & DroneState.COMMAND for n in demo)
    assert demo[-1].demo.major is CtrlState.LANDED  # type: ignore[union-attr]
    sim.receive_at(wire(at.Config("general:navdata_demo", "FALSE"), first=3), sim.time)
    sim.physics  # noqa: B018
    fast = []
    for _ in range(100):
        sim.step(0.001)
        pkt = sim.navdata_due(sim.time)
        if pkt:
            fast.append(pkt)
    assert 18 <= len(fast) <= 21  # 200 Hz over 0.1 s


def test_sequence_rules_stale_ignored_seq_1_resets() -> None:
    sim = SimDrone()
    sim.receive_at(wire(at.Comwdg(), first=10), 0.0)
    assert sim.commands_accepted == 1
    sim.receive_at(wire(at.Ref.takeoff(), first=5), 0.0)  # stale: ignored
    assert sim.commands_accepted == 1 and sim.physics.ctrl is CtrlState.LANDED
    sim.receive_at(wire(at.Ref.takeoff(), first=1), 0.0)  # seq 1 resets the counter
    assert sim.commands_accepted == 2 and sim.physics.ctrl is CtrlState.TAKEOFF


def test_garbage_at_is_ignored_and_counted() -> None:
    sim = SimDrone()
    sim.receive_at(b"\x00\xffnot an AT command", 0.0)
    sim.receive_at(b"AT*REF=1,290718208", 0.0)  # no CR
    assert sim.rejected_at == 2 and sim.physics.ctrl is CtrlState.LANDED


def test_emergency_rising_edge_toggles() -> None:
    sim = SimDrone()
    sim.receive_at(wire(at.Ref.takeoff()), 0.0)
    collect(sim, 4.0)
    assert sim.truth.flying
    sim.receive_at(wire(at.Ref.emergency(), first=2), sim.time)
    sim.receive_at(wire(at.Ref.emergency(), first=3), sim.time)  # held bit: no second toggle
    assert sim.truth.emergency and not sim.truth.flying
    collect(sim, 1.0)
    assert sim.truth.z == 0.0 and sim.state_bits() & DroneState.EMERGENCY
    sim.receive_at(wire(at.Ref.land(), first=4), sim.time)
    sim.receive_at(wire(at.Ref.emergency(), first=5), sim.time)  # new rising edge: reset
    assert not sim.truth.emergency and sim.truth.ctrl_state is CtrlState.LANDED


def test_two_second_command_timeout_hovers_and_raises_watchdog_bits() -> None:
    sim = SimDrone()
    sim.receive_at(wire(at.Ref.takeoff(), at.Comwdg()), 0.0)
    assert not sim.state_bits() & DroneState.COM_WATCHDOG
    collect(sim, 1.9)  # take-off is still going: no AT for 1.9 s is fine
    assert not sim.state_bits() & DroneState.COM_LOST
    seq = 3
    t = sim.time
    while sim.time < 5.0:  # keep the link alive while climbing
        sim.receive_at(wire(at.Ref.takeoff(), first=seq), sim.time)
        seq += 1
        collect(sim, 0.1)
    sim.receive_at(wire(at.Ref.takeoff(), at.Pcmd(1, 0.0, -1.0, 0.0, 0.0), first=seq), sim.time)
    collect(sim, 1.0)
    assert sim.truth.vx > 0.5
    collect(sim, 1.5)  # 2.5 s silent
    bits = sim.state_bits()
    assert bits & DroneState.COM_LOST and bits & DroneState.COM_WATCHDOG
    collect(sim, 3.0)
    assert abs(sim.truth.vx) < 0.05 and sim.truth.flying  # hovered on its own
    sim.receive_at(wire(at.Comwdg(), first=seq + 2), sim.time)
    bits = sim.state_bits()
    assert not bits & DroneState.COM_LOST and not bits & DroneState.COM_WATCHDOG
    assert t < sim.time


def test_config_keys_change_the_flight_envelope() -> None:
    sim = SimDrone()
    cmds = [
        at.Config("control:euler_angle_max", "0.1"),
        at.Config("control:control_vz_max", "1000"),
        at.Config("control:control_yaw", "3.0"),
        at.Config("control:altitude_max", "2000"),
        at.Config("control:altitude_max", "not a number"),  # ignored, like the drone
    ]
    sim.receive_at(wire(*cmds), 0.0)
    p = sim.physics.params
    assert p.euler_angle_max_rad == 0.1 and p.control_vz_max_m_s == 1.0
    assert p.control_yaw_rad_s == 3.0 and p.altitude_max_m == 2.0
    sim.receive_at(wire(at.Config("control:outdoor", "TRUE"), first=10), 0.0)
    p = sim.physics.params
    assert p.euler_angle_max_rad == pytest.approx(math.radians(20)) and p.control_vz_max_m_s == 1.0


def test_demo_values_follow_the_ardrone_conventions() -> None:
    sim = SimDrone(start=(4.0, 3.0, math.radians(30)))
    sim.receive_navdata_request(b"\x01", 0.0)
    sim.receive_at(wire(at.Config("general:navdata_demo", "TRUE"), at.Ref.takeoff()), 0.0)
    collect(sim, 5.0)
    sim.receive_at(wire(at.Ref.takeoff(), at.Pcmd(1, 0.5, 0, 0, 0), first=3), sim.time)
    pkts = collect(sim, 1.0)
    nav = decode_navdata(pkts[-1])
    d = nav.demo
    assert d is not None and nav.state & DroneState.FLY
    assert d.psi_mdeg == pytest.approx(-30000.0, abs=500)  # clockwise positive
    assert d.phi_mdeg > 3000  # roll right: right wing down positive
    assert d.vy_mm_s > 300  # moving right: drone vy positive
    assert d.altitude_mm == pytest.approx(800, abs=40)
    body = nav.to_body()
    assert body.vy_m_s < -0.3 and body.yaw_rad == pytest.approx(math.radians(30), abs=0.01)
    t = sim.truth
    assert t.vy < 0 and t.vx > 0  # map frame: right of a 30° heading is -y, +x


def test_gps_only_when_asked_and_only_with_an_origin() -> None:
    class Origin:
        lat_deg, lon_deg, alt_m = 36.367164, 127.363472, 60.0

    class World:
        bounds = (-50.0, 50.0, -50.0, 50.0, 0.0, 30.0)
        gps_origin = Origin()
        start = None

    exact = SimConfig(gps_noise_m=0.0)  # the conversion itself, without the receiver's noise
    sim = SimDrone(World(), start=(10.0, 20.0, 0.0), config=exact)  # type: ignore[arg-type]
    sim.receive_navdata_request(b"\x01", 0.0)
    sim.receive_at(wire(at.Config("general:navdata_demo", "TRUE")), 0.0)
    assert decode_navdata(collect(sim, 0.1)[0]).gps is None
    sim.receive_at(wire(at.Config("general:navdata_options", str(1 << TAG_GPS)), first=2), 0)
    gps = decode_navdata(collect(sim, 0.1)[0]).gps
    assert gps is not None
    # 20 m north ≈ 20 / 111 km in latitude; 10 m east ≈ 10 / (111 km · cos 36.4°)
    assert gps.latitude_deg - Origin.lat_deg == pytest.approx(20 / 110_950, rel=0.01)
    assert gps.longitude_deg - Origin.lon_deg == pytest.approx(10 / (111_320 * 0.8049), rel=0.01)


@pytest.mark.parametrize(
    ("kind", "params"),
    [
        ("earthquake", {}),
        ("link_loss", {}),
        ("link_loss", {"duration_s": -1.0}),
        ("battery", {"pct": 150.0}),
        ("battery", {"pct": float("nan")}),
        ("wind_gust", {"vx": 1.0, "vy": 0.0}),
        ("wind", {"vx": "strong", "vy": 0.0}),
        ("battery_drain", {"pct_s": 9.0}),
        ("battery_drain", {"pct_s": -1.0}),
        ("lost_markers", {}),
    ],
)
def test_bad_faults_raise_fault_error(kind: str, params: dict[str, object]) -> None:
    with pytest.raises(FaultError):
        SimDrone().inject_fault(kind, **params)  # type: ignore[arg-type]


def test_fault_aliases_used_by_the_rest_body_and_clear() -> None:
    sim = SimDrone()
    sim.inject_fault("battery", battery_pct=42.0)
    assert sim.truth.battery_pct == 42.0
    sim.inject_fault("wind", wind_x=1.0, wind_y=-2.0)
    assert sim.physics.air() == (1.0, -2.0)
    sim.inject_fault("wind", wind_x=0.5, wind_y=0.0, duration_s=1.0)  # with a duration: a gust
    assert sim.physics.air() == (1.5, -2.0)
    sim.inject_fault("link_loss", duration_s=10.0)
    assert sim.link_down
    sim.inject_fault("clear")
    assert not sim.link_down and sim.physics.air() == (0.0, 0.0)
    assert sim.truth.battery_pct == 42.0


def test_battery_drain_fault_leaks_until_cleared() -> None:
    sim = SimDrone()
    sim.inject_fault("battery_drain", drain_pct_s=1.0)  # the REST body's name
    for _ in range(1000):
        sim.step(DT)
    assert sim.truth.battery_pct == pytest.approx(100.0 - 10.0 - 10 * 0.005, abs=0.01)
    sim.inject_fault("clear")
    before = sim.truth.battery_pct
    for _ in range(1000):
        sim.step(DT)
    assert before - sim.truth.battery_pct == pytest.approx(10 * 0.005, abs=0.001)  # idle only


def test_the_battery_drains_over_the_configured_flight_time() -> None:
    """``SimConfig.flight_time_s`` (``UAVC_FLIGHT_TIME_S`` for ``serve``'s simulators): a
    hovering drone with a 240 s battery drains 100 / 240 % a second, three times the AR.Drone's."""
    drains = []
    for flight in (720.0, 240.0):
        sim = SimDrone(config=SimConfig(flight_time_s=flight))
        assert sim.physics.battery.flight_time_s == flight
        sim.physics.battery.step(10.0, motors_on=True)
        drains.append(100.0 - sim.truth.battery_pct)
    assert drains[0] == pytest.approx(1000.0 / 720.0)
    assert drains[1] == pytest.approx(3.0 * drains[0])


def test_lost_markers_fault_hides_every_marker_from_the_camera_for_its_duration() -> None:
    import cv2

    from drone.sim.world import load_world

    world = load_world("indoor")
    m = world.markers[0]
    # 1.5 m in front of the marker, at its height, facing it
    nx, ny = float(m.normal[0]), float(m.normal[1])
    pose = (
        m.position[0] + 1.5 * nx,
        m.position[1] + 1.5 * ny,
        m.position[2],
        0.0,
        0.0,
        math.atan2(-ny, -nx),
    )
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))

    def seen() -> set[int]:
        _, ids, _ = detector.detectMarkers(sim.render_frame(pose))  # type: ignore[arg-type]
        return set() if ids is None else {int(i) for i in ids.ravel()}

    sim = SimDrone(world, seed=1)
    assert m.id in seen()
    sim.inject_fault("lost_markers", duration_s=0.5)
    assert sim.markers_lost and seen() == set()
    for _ in range(60):
        sim.step(DT)
    assert not sim.markers_lost and m.id in seen()
    sim.inject_fault("lost_markers", duration_s=10.0)
    sim.inject_fault("clear")
    assert m.id in seen()


def test_bad_construction_and_dt() -> None:
    with pytest.raises(SimConfigError):
        SimDrone(start=(100.0, 0.0, 0.0))
    with pytest.raises(SimConfigError):
        SimDrone().step(-1.0)
    with pytest.raises(SimConfigError):
        SimDrone().step(float("nan"))


def lockstep(**kw: object) -> tuple[InMemoryLink, DriverProtocol, SimDrone]:
    sim = SimDrone(**kw)  # type: ignore[arg-type]
    proto = DriverProtocol()
    link = InMemoryLink(proto, sim)
    link.start()
    return link, proto, sim


def test_lockstep_flight_through_the_real_code_path() -> None:
    link, proto, sim = lockstep(seed=7)
    events = link.run(1.0)
    assert any(isinstance(e, HandshakeDone) for e in events)
    assert sim.navdata_rate_hz == 15.0
    proto.takeoff()
    link.run(5.0)
    assert proto.latest is not None and proto.latest.demo is not None
    assert proto.latest.demo.major is CtrlState.HOVERING
    assert proto.latest.to_body().altitude_m == pytest.approx(0.8, abs=0.05)
    proto.move(0.0, -0.3, 0.0, 0.0)
    link.run(2.0)
    assert sim.truth.x > 4.5 and proto.latest.to_body().vx_m_s > 0.3
    proto.land()
    link.run(3.0)
    assert sim.truth.ctrl_state is CtrlState.LANDED and not sim.truth.flying
    assert link.stats.at_datagrams >= 30 * 11  # ≥ 30 Hz all along


def test_lockstep_is_deterministic_for_a_seed() -> None:
    def fly(seed: int) -> tuple[float, ...]:
        link, proto, sim = lockstep(seed=seed)
        link.run(1.0)
        proto.takeoff()
        link.run(4.0)
        proto.move(0.2, -0.4, 0.1, 0.3)
        link.run(2.0)
        assert proto.latest is not None and proto.latest.demo is not None
        d = proto.latest.demo
        return (sim.truth.x, sim.truth.y, d.altitude_mm, d.vx_mm_s)

    assert fly(5) == fly(5)
    assert fly(5) != fly(6)  # sensor noise differs


def test_lockstep_emergency_lands_hard_and_reset_recovers() -> None:
    link, proto, sim = lockstep()
    link.run(1.0)
    proto.takeoff()
    link.run(5.0)
    proto.emergency()
    link.run(0.02)
    assert sim.truth.emergency  # reached the drone in the very next tick
    link.run(1.5)
    assert sim.truth.z == 0.0
    assert proto.latest is not None and proto.latest.state & DroneState.EMERGENCY
    proto.reset()
    link.run(0.5)
    assert not sim.truth.emergency and sim.truth.ctrl_state is CtrlState.LANDED
    proto.takeoff()
    link.run(5.0)
    assert sim.truth.flying


def test_lockstep_link_loss_fault_and_recovery() -> None:
    link, proto, sim = lockstep()
    link.run(1.0)
    proto.takeoff()
    link.run(5.0)
    proto.move(0.0, -0.5, 0.0, 0.0)
    link.run(1.0)
    assert sim.truth.vx > 0.5
    sim.inject_fault("link_loss", duration_s=4.5)
    events = link.run(4.4)
    assert [type(e) for e in events] == [LinkLost]
    assert sim.truth.flying and abs(sim.truth.vx) < 0.1  # the 2 s watchdog made it hover
    assert proto.state.value == "lost"
    events = link.run(0.5)
    assert len([e for e in events if isinstance(e, LinkRestored)]) == 1
    proto.move(0.0, 0.0, 0.5, 0.0)
    link.run(0.5)
    assert sim.truth.vz > 0.2  # commands flow again after recovery
    assert proto.state.value == "ready"


def test_lockstep_low_battery_refuses_takeoff_and_sets_the_bit() -> None:
    link, proto, sim = lockstep()
    sim.inject_fault("battery", pct=15.0)
    link.run(1.0)
    proto.takeoff()
    link.run(3.0)
    assert not sim.truth.flying
    assert proto.latest is not None and proto.latest.state & DroneState.VBAT_LOW
    sim.inject_fault("battery", pct=60.0)
    link.run(3.0)
    assert sim.truth.flying  # the take-off bit is level-triggered


def test_lockstep_wind_gust_pushes_then_the_drone_holds() -> None:
    link, proto, sim = lockstep()
    link.run(1.0)
    proto.takeoff()
    link.run(5.0)
    x0 = sim.truth.x
    sim.inject_fault("wind_gust", vx=0.0, vy=-5.0, duration_s=1.0)
    link.run(1.0)
    assert proto.latest is not None and proto.latest.state & DroneState.WIND
    assert sim.truth.y < 3.0 - 0.2 and abs(sim.truth.x - x0) < 0.05
    link.run(3.0)
    assert math.hypot(sim.truth.vx, sim.truth.vy) < 0.05


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(st.lists(st.binary(max_size=200), max_size=20))
def test_arbitrary_at_datagrams_never_crash_the_simulator(datagrams: list[bytes]) -> None:
    sim = SimDrone()
    for d in datagrams:
        sim.receive_at(d, sim.time)
        sim.receive_navdata_request(d, sim.time)
        sim.step(0.01)
    assert sim.physics.ctrl is CtrlState.LANDED  # random bytes are not a take-off command


def test_lockstep_with_a_clock_that_does_not_start_at_zero() -> None:
    sim = SimDrone()
    proto = DriverProtocol()
    link = InMemoryLink(proto, sim)
    now = 1000.0
    link.start(now)
    for _ in range(100):
        link.step(now, DT)
        now += DT
    assert proto.handshake_done
    proto.takeoff()
    for _ in range(500):
        link.step(now, DT)
        now += DT
    assert sim.truth.ctrl_state is CtrlState.HOVERING and not sim.command_lost
    for _ in range(300):  # the rig stops pumping AT: only physics runs
        sim.step(DT)
    assert sim.command_lost
