"""``LockstepRig``: simulator, wire protocol, sensors, estimator, controller and tasks stepped in
order on one virtual clock — no sockets, no sleeping, deterministic for a seed (DESIGN §3).

One tick of ``dt`` (default 10 ms = the controller period), per drone, in this order:

1. ``InMemoryLink.step``: the driver core's AT datagrams → ``SimDrone`` → physics → navdata
   bytes → the driver core → events → ``ARDroneVehicle.on_driver_event`` (EKF predict/update);
2. camera at ``camera_rate_hz`` (15 fps as the AR.Drone's stream): ``SimDrone.render_frame``
   at the true pose, delivered to ``ARDroneVehicle.on_frame`` ``frame_latency_s`` later with its
   capture time (so the EKF's late-measurement path runs as it does live);
3. ``ARDroneVehicle.control_step`` (the same code the 100 Hz thread runs);
4. extra steppers (``add_stepper(fn(now, dt))``: task managers, fleet managers, monitors).

Usage::

    rig = LockstepRig(load_world("indoor"), n_drones=1, seed=0)
    rig.vehicles[0].takeoff()
    rig.run_until(lambda: rig.vehicles[0].snapshot().flying, timeout_s=10)

``known_start=True`` (default) starts each EKF at its drone's true start pose, as a drone
standing on its surveyed home station; ``False`` makes it find itself from markers.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from drone.ardrone.protocol import DriverProtocol
from drone.ardrone.vehicle import ARDroneVehicle
from drone.camera import CameraModel
from drone.control.clock import VirtualClock
from drone.sim.drone import SimConfig, SimDrone
from drone.sim.link import InMemoryLink

Stepper = Callable[[float, float], None]


class LockstepRig:
    """See the module docstring.

    Args:
        world: the ``World`` to fly in.
        n_drones: drones ``uav1``…``uavN``; starts are the world's stations in order (or
            ``starts``).
        seed: seeds each simulator (drone i gets ``seed + i``).
        camera: render and process camera frames (slower; needed for marker localisation).
        starts: ``(x, y, yaw_rad)`` per drone on the floor.
        dt: tick length in seconds (controller period).
    """

    def __init__(
        self,
        world: Any,
        n_drones: int = 1,
        seed: int = 0,
        camera: bool = True,
        *,
        starts: Sequence[tuple[float, float, float]] | None = None,
        dt: float = 0.01,
        camera_rate_hz: float = 15.0,
        frame_latency_s: float = 0.04,
        known_start: bool = True,
        sim_config: SimConfig | None = None,
    ) -> None:
        if n_drones < 1:
            raise ValueError(f"n_drones must be >= 1, got {n_drones}")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be positive, got {dt!r}")
        self.world = world
        self.dt = dt
        self.clock = VirtualClock()
        self.camera = camera
        self.camera_period_s = 1.0 / camera_rate_hz
        self.frame_latency_s = frame_latency_s
        self.sims: list[SimDrone] = []
        self.links: list[InMemoryLink] = []
        self.vehicles: list[ARDroneVehicle] = []
        self._steppers: list[Stepper] = []
        self._frames: list[deque[tuple[float, float, np.ndarray]]] = []
        self._next_frame = 0.0
        self.ticks = 0
        cam_model = CameraModel() if camera else None
        for i in range(n_drones):
            if starts is not None:
                start = starts[i]
            elif getattr(world, "stations", ()) and i < len(world.stations):
                p = world.stations[i].position
                start = (p[0], p[1], world.start.yaw_rad)
            else:
                start = None
            cfg = sim_config or SimConfig()
            from dataclasses import replace

            sim = SimDrone(world, start=start, config=replace(cfg, seed=seed + i))
            proto = DriverProtocol()
            link = InMemoryLink(proto, sim)
            link.start(self.clock.now())
            v = ARDroneVehicle(f"uav{i + 1}", world, proto, camera=cam_model, clock=self.clock)
            if known_start:
                t = sim.truth
                v.ekf.reset(self.clock.now(), t.x, t.y, t.z, t.yaw_rad)
            self.sims.append(sim)
            self.links.append(link)
            self.vehicles.append(v)
            self._frames.append(deque())

    @property
    def vehicle(self) -> ARDroneVehicle:
        """The first (or only) vehicle."""
        return self.vehicles[0]

    @property
    def sim(self) -> SimDrone:
        return self.sims[0]

    def add_stepper(self, fn: Stepper) -> None:
        """Call ``fn(now, dt)`` at the end of every tick (after the controllers)."""
        self._steppers.append(fn)

    def step(self, dt: float | None = None) -> None:
        """Advance every part by one tick of ``dt`` (default ``self.dt``)."""
        dt = self.dt if dt is None else dt
        now = self.clock.now()
        later = now + dt
        for link, v in zip(self.links, self.vehicles, strict=True):
            for ev in link.step(now, dt):
                v.on_driver_event(ev)
        self.clock.set(later)
        if self.camera:
            if later + 1e-9 >= self._next_frame:
                self._next_frame += self.camera_period_s
                for sim, q in zip(self.sims, self._frames, strict=True):
                    frame = sim.render_frame()
                    if frame is not None:
                        q.append((later + self.frame_latency_s, later, frame))
            for v, q in zip(self.vehicles, self._frames, strict=True):
                while q and q[0][0] <= later + 1e-9:
                    _, t_capture, frame = q.popleft()
                    v.on_frame(frame, t_capture)
        for v in self.vehicles:
            v.control_step(later, dt)
        for fn in self._steppers:
            fn(later, dt)
        self.ticks += 1

    def run(self, duration_s: float) -> None:
        """Step for ``duration_s`` seconds of virtual time."""
        for _ in range(max(0, round(duration_s / self.dt))):
            self.step()

    def run_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Step until ``predicate()`` is true (checked after each tick) or ``timeout_s`` passes.

        Returns whether the predicate became true.
        """
        end = self.clock.now() + timeout_s
        while self.clock.now() < end - 1e-9:
            self.step()
            if predicate():
                return True
        return bool(predicate())

    def wait_link(self, timeout_s: float = 3.0) -> bool:
        """Run until every driver finished its navdata handshake."""
        links = self.links
        return self.run_until(lambda: all(k.protocol.handshake_done for k in links), timeout_s)

    def takeoff_all(self, timeout_s: float = 10.0) -> bool:
        """Handshake, take off every drone and wait until all are hovering."""
        if not self.wait_link():
            return False
        for v in self.vehicles:
            v.takeoff()
        return self.run_until(
            lambda: all(
                s.truth.flying and s.truth.ctrl_state.name in ("HOVERING", "FLYING")
                for s in self.sims
            ),
            timeout_s,
        )
