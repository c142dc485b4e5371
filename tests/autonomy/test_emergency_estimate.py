"""An emergency stop raises no "position estimate disagrees" alarm (issue 14, the flip to
``--vehicles process``).

The motors cut, the drone falls at g and stops dead on the floor. The EKF's vertical model
(constant velocity, σa,z = 3 m/s²) cannot follow either, so before the fix its gate rejected the
fall's vertical speed three packets in a row ("disagrees … vertical speed"), then the floor's
altitude while the estimate sank 0.4 m below it, and re-initialised both: the ANS estimator
monitor told the operator after every emergency stop, inline or in a vehicle process alike.
Now navdata flagged EMERGENCY is fused ungated and the estimate follows the fall.

In lockstep (virtual clock, no sockets): the drone's own :class:`Vehicle` and its supervisor's
:class:`SensorAgreementMonitor`, as ``serve`` wires them.
"""

from __future__ import annotations

import pytest

from drone.sim.world import load_world
from drone.supervisor import Phase
from drone.supervisor.estimator import SensorAgreementMonitor

from .flight import Flight


@pytest.mark.parametrize(("seed", "climb_m"), [(0, 0.0), (1, 1.0)])
def test_an_emergency_stop_raises_no_estimator_alarm(seed: int, climb_m: float) -> None:
    world = load_world("indoor")
    f = Flight.make(world, seed=seed, camera=False)
    f.submit({"action": "takeoff"})
    if climb_m:
        f.submit({"action": "move", "direction": "up", "distance": climb_m})
    assert f.run_until_idle(20.0)
    vehicle, sim, ekf = f.rig.vehicle, f.rig.sim, f.rig.vehicle.ekf
    high = sim.truth.z
    assert high > 0.6 + climb_m
    monitor = SensorAgreementMonitor()
    alarms, worst = [], 0.0
    vehicle.emergency()
    end = f.rig.clock.now() + 3.0
    while f.rig.clock.now() < end:
        f.rig.step()
        alarm = monitor.check(vehicle.snapshot(), Phase.EMERGENCY, f.rig.clock.now())
        if alarm is not None:
            alarms.append(alarm.text)
        est, tr = ekf.latest, sim.truth
        if abs(est.t - tr.t_s) < 1e-6:  # a navdata instant: estimate and truth share a stamp
            worst = max(worst, abs(est.z - tr.z))
    assert sim.truth.emergency and sim.truth.z < 0.01  # it fell all the way
    assert vehicle.snapshot().emergency
    assert alarms == []  # before: "… disagrees … (vertical speed)", then "… I reset it …"
    assert ekf.stats.navdata_reinits == 0 and ekf.stats.navdata_rejected == 0, ekf.stats
    assert worst < 0.15 + 0.1 * climb_m, (high, worst)  # before: 0.44 m below the floor
