"""Shared lockstep flight harness for the closed-loop tests (no sockets, virtual clock)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drone.lockstep import LockstepRig
from drone.perception.ekf import wrap
from drone.sim.world import World
from server.tasks import TaskManager, TaskNotice


@dataclass
class Flight:
    rig: LockstepRig
    tm: TaskManager
    events: list[TaskNotice] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)

    @classmethod
    def make(cls, world: World, *, seed: int = 0, camera: bool = True, **kw: Any) -> Flight:
        rig = LockstepRig(world, seed=seed, camera=camera, **kw)
        tm = TaskManager(rig.vehicle, world, rig.clock)
        f = cls(rig, tm)
        tm.on_event(f.events.append)
        rig.add_stepper(lambda now, dt: tm.step(now))
        rig.add_stepper(f._record)
        assert rig.wait_link()
        return f

    def _record(self, now: float, dt: float) -> None:
        est = self.rig.vehicle.ekf.latest
        tr = self.rig.sim.truth
        # compare at navdata instants, where the estimate and the truth share a time stamp
        if abs(est.t - tr.t_s) > 1e-6 or not (est.localised and tr.flying):
            return
        e = np.array([est.x - tr.x, est.y - tr.y, est.z - tr.z, wrap(est.yaw_rad - tr.yaw_rad)])
        self.nees.append(float(e @ np.linalg.solve(est.P[:4, :4], e)))

    def submit(self, *commands: dict[str, Any]) -> None:
        decisions = self.tm.submit(list(commands))
        assert all(d.accepted for d in decisions), decisions

    def run_until_idle(self, timeout_s: float) -> bool:
        tm = self.tm
        return self.rig.run_until(lambda: tm.current is None and not tm.queued, timeout_s)

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events]

    def truth_error(self, x: float, y: float, z: float, yaw: float) -> tuple[float, float]:
        tr = self.rig.sim.truth
        d = math.dist((tr.x, tr.y, tr.z), (x, y, z))
        return d, abs(math.degrees(wrap(tr.yaw_rad - yaw)))

    @property
    def collisions(self) -> int:
        return int(self.rig.sim.physics.collisions)
