"""One vehicle interface: the AR.Drone's and the MAVLink vehicle both implement
:class:`drone.vehicle.Vehicle` (typed snapshot, modes, actions), and the parts above the drivers
(task executor, supervisor) run on either through it alone."""

from __future__ import annotations

import inspect

from drone.ardrone.vehicle import ARDroneVehicle
from drone.control.clock import VirtualClock
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.vehicle import MavlinkVehicle
from drone.sim.world import load_world
from drone.supervisor import Phase, supervise
from drone.vehicle import Vehicle, VehicleSnapshot
from server.tasks import TaskManager

WORLD = load_world("indoor")


def _both() -> list[Vehicle]:
    clock = VirtualClock(0.0)
    return [
        ARDroneVehicle("uav1", WORLD, clock=clock),
        MavlinkVehicle(
            "uav2", load_world("outdoor"), GcsProtocol(request_streams=False), clock=clock
        ),
    ]


def test_both_vehicles_implement_the_one_interface_with_the_same_signatures() -> None:
    for v in _both():
        assert isinstance(v, Vehicle), type(v).__name__
        for name in ("jog", "set_setpoint", "stop"):
            want = inspect.signature(getattr(Vehicle, name))
            got = inspect.signature(getattr(type(v), name))
            assert list(got.parameters) == list(want.parameters), (type(v).__name__, name)
        assert isinstance(v.snapshot(), VehicleSnapshot)
    assert [v.holds_position for v in _both()] == [False, True]  # an autopilot holds its own


def test_the_task_executor_and_the_supervisor_take_either() -> None:
    for v in _both():
        tm = TaskManager(v, WORLD, v.clock)
        sup = supervise(v, tm, WORLD)
        assert sup.phase(v.snapshot()) is Phase.GROUNDED
        assert sup.step(0.0) == []  # nothing heard from the drone yet: no alarm
        decision = tm.submit([{"action": "move", "direction": "up", "distance": 1}])[0]
        assert not decision.accepted  # on the ground: refused with the reason, on both
