"""Stations that charge (issue 28): a world's charging pad charges a drone that lands on it at
the pad's rate; the AR.Drone's drain is unchanged; a drone that has not landed there since the
start or since a battery fault does not charge."""

from __future__ import annotations

import dataclasses

import pytest

from drone.sim.drone import SimDrone
from drone.sim.world import PAD_RADIUS_M, WorldError, load_world

DT = 0.05


def _fly_and_land(sim: SimDrone, seconds: float = 20.0) -> float:
    """Take off, hover ``seconds``, land; returns the charge on touching down."""
    ph = sim.physics
    assert ph.takeoff()
    for _ in range(round(seconds / DT)):
        sim.step(DT)
    ph.land()
    while ph.motors_on:
        sim.step(DT)
    return ph.battery.pct


def test_sample_worlds_name_charging_pads_at_one_percent_a_second() -> None:
    for name in ("outdoor", "indoor"):
        world = load_world(name)
        assert world.stations and all(s.charge_pct_s == 1.0 for s in world.stations)
        assert world.charge_pct_s == 1.0
        home = world.stations[0]
        assert world.pad_at(home.position[0] + 0.2, home.position[1]) == home
        assert world.pad_at(home.position[0] + 30.0, home.position[1] + 30.0) is None
        listed = world.to_dict()["stations"][0]
        assert listed["charge_pct_s"] == 1.0 and listed["radius_m"] == PAD_RADIUS_M


def test_a_drone_landed_on_its_pad_charges_at_the_pads_rate() -> None:
    world = load_world("outdoor")
    sim = SimDrone(world, start=(0.0, 0.0, 0.0), seed=1)
    sim.physics.battery.drain_to(50.0)
    for _ in range(round(10.0 / DT)):  # on the pad since the start: no charging yet
        sim.step(DT)
    assert sim.physics.battery.pct == pytest.approx(50.0 - 10.0 * 0.005, abs=0.01)
    landed = _fly_and_land(sim)
    assert landed < 50.0  # the flight drained it (the paper's model)
    assert sim.charging
    for _ in range(round(10.0 / DT)):
        sim.step(DT)
    # the pad's 1 %/s, less the electronics' own draw (0.005 %/s, drone/sim/battery.py)
    assert sim.physics.battery.pct == pytest.approx(landed + 10.0 * (1.0 - 0.005), abs=0.01)
    for _ in range(round(120.0 / DT)):
        sim.step(DT)
    assert sim.physics.battery.pct == 100.0  # full, and no further
    assert sim.physics.takeoff()
    sim.step(DT)
    assert not sim.charging  # motors on: off the charger


def test_no_charge_off_the_pad_after_a_fault_or_on_a_plain_pad() -> None:
    world = load_world("outdoor")
    far = SimDrone(world, start=(20.0, 20.0, 0.0), seed=1)
    landed = _fly_and_land(far, 5.0)
    for _ in range(round(10.0 / DT)):
        far.step(DT)
    assert far.physics.battery.pct <= landed and not far.charging

    sim = SimDrone(world, start=(0.0, 0.0, 0.0), seed=1)
    _fly_and_land(sim, 5.0)
    sim.inject_fault("battery", pct=15.0)
    for _ in range(round(5.0 / DT)):
        sim.step(DT)
    assert sim.physics.battery.pct < 15.0  # a battery fault holds until the next landing

    plain = dataclasses.replace(
        world, stations=tuple(dataclasses.replace(s, charge_pct_s=0.0) for s in world.stations)
    )
    pad = SimDrone(plain, start=(0.0, 0.0, 0.0), seed=1)
    landed = _fly_and_land(pad, 5.0)
    for _ in range(round(5.0 / DT)):
        pad.step(DT)
    assert pad.physics.battery.pct <= landed


@pytest.mark.parametrize(
    ("value", "why"),
    [(-1.0, "must be >= 0"), (50.0, "must be <= 10"), ("fast", "expected a number")],
)
def test_a_bad_charge_rate_names_the_field(tmp_path, value: object, why: str) -> None:
    text = (
        "name: t\nkind: indoor\n"
        "bounds: {x_min: 0, x_max: 4, y_min: 0, y_max: 4, z_min: 0, z_max: 3}\n"
        f"stations:\n  - {{id: a, position: [1, 1, 0], charge_pct_s: {value!r}}}\n"
    )
    path = tmp_path / "t.yaml"
    path.write_text(text.replace("'", '"'))
    with pytest.raises(WorldError, match=rf"stations\[0\]\.charge_pct_s.*{why}"):
        load_world(path)
