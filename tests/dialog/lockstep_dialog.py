"""One drone's dialog manager, task manager and vehicle in lockstep against the simulator
(camera off), with the replies and the audit log kept for the test to read."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drone.lockstep import LockstepRig
from drone.sim.world import World, load_world
from drone.supervisor import keep_away_of
from server.dialog.adapters import TaskManagerPort, VehicleAdapter
from server.dialog.manager import DialogManager
from server.graph import Graph
from server.language.nlu import NLU
from server.settings import Settings
from server.store import AuditLog
from server.tasks import TaskManager
from tests.supervisor.snaps import supervised


@dataclass
class DialogRig:
    rig: LockstepRig
    tm: TaskManager
    dm: DialogManager
    audit: AuditLog
    replies: list[dict[str, Any]] = field(default_factory=list)


def dialog_rig(
    seed: int,
    start: tuple[float, float, float] | None = (4.0, 2.0, 0.0),
    *,
    settings: Settings | None = None,
    world_name: str = "indoor",
    camera: bool = False,
    known_start: bool = True,
    drone: str = "uav1",
    drones: tuple[str, ...] = ("uav1",),
    world: World | None = None,
    people: bool = False,
) -> DialogRig:
    """``world_name`` (indoor by default) with the drone landed at ``start`` (None: the world's
    first station); every part stepped by the rig. ``drone``/``drones``: this dialog's name and
    the fleet's (for sentences that name their drone)."""
    world = world or load_world(world_name)
    rig = LockstepRig(
        world,
        seed=seed,
        camera=camera,
        starts=None if start is None else [start],
        known_start=known_start,
    )
    # ``people``: the simulator tracks the world's people for the drone, as ``serve`` does
    keep = keep_away_of(world, rig.sim.people) if people else None
    tm = TaskManager(rig.vehicle, world, rig.clock, keep_away=keep)
    rig.add_stepper(lambda now, dt: tm.step(now))
    graph = Graph()
    replies: list[dict[str, Any]] = []
    graph.subscribe("/console/reply", replies.append, type="uav_console/Reply")
    audit = AuditLog(":memory:", clock=rig.clock.now)
    dm = DialogManager(
        graph,
        settings or Settings(),
        TaskManagerPort(tm),
        VehicleAdapter(rig.vehicle, world),
        None,
        audit,
        rig.clock.now,
        nlu=NLU(),
        drone=drone,
        drones=lambda: list(drones),
    )
    rig.add_stepper(lambda now, dt: dm.step(now))
    supervised(rig, tm, world, dm, settings or Settings(), keep_away=keep)
    return DialogRig(rig, tm, dm, audit, replies)
