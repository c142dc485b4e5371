"""Issue 13 §12: navdata pressure and temperature. The simulator models the barometer (ISA at
the drone's height above sea level), sends option 21 when ``general:navdata_options`` asks for
it, the codec decodes it, the vehicle asks for it, and ``/ardrone/navdata`` carries it in
ardrone_autonomy's ``pressure`` (Pa) and ``temp`` (0.1 °C) — before, both read 0."""

from __future__ import annotations

import struct

import pytest

from drone.ardrone import at
from drone.ardrone.navdata import (
    TAG_PRESSURE_RAW,
    CtrlState,
    DroneState,
    Navdata,
    PressureRaw,
    decode_navdata,
    encode_navdata,
    ros_navdata_fields,
)
from drone.lockstep import LockstepRig
from drone.sim.drone import SimDrone
from drone.sim.world import load_world

DT = 0.005


def _wire(*commands: at.ATCommand, first: int = 1) -> bytes:
    (datagram,) = at.ATEncoder(first_seq=first).pack(commands)
    return datagram


def _last(sim: SimDrone, seconds: float) -> Navdata:
    pkt = None
    for _ in range(round(seconds / DT)):
        sim.step(DT)
        pkt = sim.navdata_due(sim.time) or pkt
    assert pkt is not None
    return decode_navdata(pkt)


def test_option_21_layout_matches_navdata_pressure_raw_t() -> None:
    """tag u16, size u16 (18), i32 up, i16 ut, i32 Temperature_meas, i32 Pression_meas."""
    nav = Navdata(DroneState(0), 1, pressure=PressureRaw(-7, 300, 215, 101_234))
    data = encode_navdata(nav)
    assert data[16:34] == struct.pack("<HHihii", 21, 18, -7, 300, 215, 101_234)
    got = decode_navdata(data)
    assert got.pressure == PressureRaw(-7, 300, 215, 101_234)
    assert got.pressure.temperature_c == pytest.approx(21.5)
    fields = ros_navdata_fields(got)
    assert (fields["pressure"], fields["temp"]) == (101_234, 215)


def test_a_wrong_size_tag_21_is_skipped_as_unknown() -> None:
    body = struct.pack("<IIII", 0x55667788, 0, 1, 0) + struct.pack("<HH", 21, 8) + b"\0" * 4
    data = body + struct.pack("<HHI", 0xFFFF, 8, sum(body) & 0xFFFFFFFF)
    nav = decode_navdata(data)
    assert nav.pressure is None and nav.unknown == ((21, b"\0" * 4),)


def _sim(world_name: str, seed: int = 3) -> SimDrone:
    world = load_world(world_name)
    sim = SimDrone(world, seed=seed)
    sim.receive_navdata_request(b"\x01", 0.0)
    sim.receive_at(_wire(at.Config("general:navdata_demo", "TRUE")), 0.0)
    return sim


def test_the_simulator_sends_the_barometer_only_when_asked() -> None:
    sim = _sim("indoor")
    assert _last(sim, 0.2).pressure is None  # pyardrone and the like get demo only
    sim.receive_at(
        _wire(at.Config("general:navdata_options", str(1 << TAG_PRESSURE_RAW)), first=2), 0
    )
    p = _last(sim, 0.2).pressure
    assert p is not None
    assert p.pressure_pa == pytest.approx(101_325, abs=40)  # sea level, on the floor
    assert p.temperature_c == pytest.approx(21.0, abs=0.5)  # a heated room


def test_outdoor_pressure_follows_the_field_elevation_and_the_height() -> None:
    sim = _sim("outdoor")
    sim.receive_at(
        _wire(at.Config("general:navdata_options", str(1 << TAG_PRESSURE_RAW)), first=2), 0
    )
    samples = [_last(sim, 0.07).pressure for _ in range(30)]
    ground = sum(p.pressure_pa for p in samples if p) / 30
    # ISA at 60 m: 101325·(1 − 2.25577e-5·60)^5.25588 ≈ 100 604 Pa; 15 − 0.39 °C
    assert ground == pytest.approx(100_604, abs=10)
    assert samples[-1].temperature_c == pytest.approx(14.6, abs=0.5)
    sim.physics.ctrl = CtrlState.HOVERING  # hovering 2.5 m up: ~12 Pa per metre less
    sim.physics.body.z = 2.5
    high = sum(_last(sim, 0.07).pressure.pressure_pa for _ in range(30)) / 30
    assert ground - high == pytest.approx(29.8, abs=8)


def test_the_vehicle_asks_for_it_and_navdata_carries_it() -> None:
    rig = LockstepRig(load_world("indoor"), seed=2, camera=False)
    seen: list[Navdata] = []
    rig.vehicle.add_navdata_listener(lambda nav, now: seen.append(nav))
    assert rig.wait_link()
    rig.run(0.5)
    assert seen[-1].pressure is not None
    fields = ros_navdata_fields(seen[-1])
    assert 100_000 < fields["pressure"] < 102_500 and 190 < fields["temp"] < 230
