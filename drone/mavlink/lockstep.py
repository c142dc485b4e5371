"""``MavlinkLockstepRig``: simulated PX4 autopilots and the console's MAVLink vehicles on one
virtual clock (DESIGN §3 lockstep), the counterpart of ``drone.lockstep.LockstepRig``.

Each tick, per drone: the console's protocol bytes → ``SimAutopilot`` (physics, its own
position controller) → telemetry bytes → the protocol → events → ``MavlinkVehicle.on_event``;
then the extra steppers (task managers, fleet managers). The bytes are the real MAVLink 2
frames, so lockstep exercises the same codec, command and mission code as the sockets do.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from drone.control.clock import VirtualClock
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.link import MavlinkMemoryLink
from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.vehicle import MavlinkVehicle

Stepper = Callable[[float, float], None]


class MavlinkLockstepRig:
    """See the module docstring.

    Args:
        world: the ``World`` (a GPS world: ``outdoor``).
        n_drones: drones ``uav1``…``uavN`` standing on the world's stations in order.
        dt: tick length (s).
        autopilot_kwargs: passed to each ``SimAutopilot`` (e.g. ``refuse_all``).
    """

    def __init__(
        self,
        world: Any,
        n_drones: int = 1,
        *,
        dt: float = 0.02,
        starts: Sequence[tuple[float, float, float]] | None = None,
        names: Sequence[str] | None = None,
        autopilot_kwargs: dict[str, Any] | None = None,
    ) -> None:
        if n_drones < 1:
            raise ValueError(f"n_drones must be >= 1, got {n_drones}")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be positive, got {dt!r}")
        self.world = world
        self.dt = dt
        self.clock = VirtualClock()
        self.autopilots: list[SimAutopilot] = []
        self.links: list[MavlinkMemoryLink] = []
        self.vehicles: list[MavlinkVehicle] = []
        self._steppers: list[Stepper] = []
        self.ticks = 0
        for i in range(n_drones):
            if starts is not None:
                start = starts[i]
            elif getattr(world, "stations", ()) and i < len(world.stations):
                p = world.stations[i].position
                start = (p[0], p[1], world.start.yaw_rad)
            else:
                start = None
            ap = SimAutopilot(world, start=start, **(autopilot_kwargs or {}))
            proto = GcsProtocol()
            link = MavlinkMemoryLink(proto, ap)
            name = names[i] if names else f"uav{i + 1}"
            self.autopilots.append(ap)
            self.links.append(link)
            self.vehicles.append(MavlinkVehicle(name, world, proto, clock=self.clock))

    @property
    def vehicle(self) -> MavlinkVehicle:
        return self.vehicles[0]

    @property
    def autopilot(self) -> SimAutopilot:
        return self.autopilots[0]

    @property
    def sims(self) -> list[SimAutopilot]:
        """The simulated vehicles (``truth``, ``physics``, ``inject_fault`` as ``SimDrone``)."""
        return self.autopilots

    def add_stepper(self, fn: Stepper) -> None:
        self._steppers.append(fn)

    def step(self, dt: float | None = None) -> None:
        dt = self.dt if dt is None else dt
        now = self.clock.now()
        for link, v in zip(self.links, self.vehicles, strict=True):
            events = link.step(now, dt)
            for ev in events:
                v.on_event(ev)
        later = now + dt
        self.clock.set(later)
        for fn in self._steppers:
            fn(later, dt)
        self.ticks += 1

    def run(self, duration_s: float) -> None:
        for _ in range(max(0, round(duration_s / self.dt))):
            self.step()

    def run_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        end = self.clock.now() + timeout_s
        while self.clock.now() < end - 1e-9:
            self.step()
            if predicate():
                return True
        return bool(predicate())

    def wait_link(self, timeout_s: float = 5.0) -> bool:
        """Until every vehicle is discovered and has a home position."""
        return self.run_until(
            lambda: all(
                v.protocol.connected and v.protocol.telemetry.home is not None
                for v in self.vehicles
            ),
            timeout_s,
        )

    def takeoff_all(self, timeout_s: float = 20.0) -> bool:
        if not self.wait_link():
            return False
        for v in self.vehicles:
            v.takeoff()
        return self.run_until(
            lambda: all(v.snapshot().ctrl_state in ("HOVERING", "FLYING") for v in self.vehicles),
            timeout_s,
        )
