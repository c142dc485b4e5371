"""``FleetService``: the fleet inside one server process, for the composition root.

Usage (``server/runtime.py``)::

    fleet = FleetService(graph, world)
    for stack in drones.values():           # in-process drones (``--fleet N``)
        fleet.add_local(stack.name, stack.vehicle, stack.tasks)
    await fleet.start()
    routers.append(fleet.router())          # mounted under /api/v1: /missions, /fleet
    ...
    await fleet.stop()

Vehicles on the bus (``uav-console vehicle --bus-connect``) need nothing here: their LTM status
and plans travel on the bus, through the central role (:meth:`FleetService.join_bus`).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Sequence
from typing import Any

from fastapi import APIRouter, Depends, params

from drone.vehicle import Vehicle
from server.fleet.central import CentralPatrol, make_patrol_router
from server.fleet.ctm import CentralTaskManager
from server.fleet.failover import CentralRole, standby_guard
from server.fleet.geo import origin_of
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import PATROL_SERVICE, PATROL_SERVICE_TYPE, Handoff
from server.fleet.node import CtmNode, LtmNode
from server.fleet.planner import FlightModel, StationModel
from server.fleet.router import CentralRoleInfo, make_fleet_router
from server.fleet.stations import station_positions
from server.graph import Graph
from server.timewarp import guard_s


def station_model(world: Any) -> StationModel:
    """How the world's stations restore a drone: its charging pads' rate (``charge_pct_s``),
    else the swap of :class:`StationModel` (a world with plain pads)."""
    rate = float(getattr(world, "charge_pct_s", 0.0) or 0.0)
    return StationModel(charge_pct_s=rate) if rate > 0 else StationModel()


class FleetService:
    """The CTM on the graph plus one in-process LTM per local drone."""

    def __init__(
        self,
        graph: Graph,
        world: Any,
        *,
        clock: Callable[[], float] = time.monotonic,
        model: FlightModel | None = None,
        stations: StationModel | None = None,
        ltm_rate_hz: float = 5.0,
    ) -> None:
        self.graph = graph
        self.world = world
        self.clock = clock
        self.ctm = CentralTaskManager(
            lost_after_s=guard_s(3.0),  # the CTM's default, in wall seconds (server.timewarp)
            model=model,
            stations=stations or station_model(world),
            origin=origin_of(world),
            world=world,
        )
        self.node = CtmNode(graph, self.ctm, clock=clock)
        # the console's Central button and voice (start/stop the world's patrol)
        self.central = CentralPatrol(self.ctm, world, clock=clock, on_change=self.node.poke)
        self.ltm_nodes: list[LtmNode] = []
        self.period_s = 1.0 / ltm_rate_hz
        self._task: asyncio.Task[None] | None = None
        # this console's part in the central role, when it is on a bus (server.fleet.failover)
        self.role: CentralRole | None = None

    async def join_bus(self, session: Any, fleet: str, console: str) -> CentralRole:
        """Take part in the central role's election on the bus (after :meth:`start`)."""
        self.role = CentralRole(self, session, fleet, console, clock=self.clock)
        await self.role.start()
        return self.role

    def add_local(self, name: str, vehicle: Vehicle, tasks: Any) -> LocalTaskManager:
        """An in-process drone joins the fleet (its station: the world's n-th station)."""
        pad = station_positions(self.world, len(self.ltm_nodes) + 1)[-1]
        ltm = LocalTaskManager(
            name, vehicle, tasks, pad, origin=origin_of(self.world), model=self.ctm.model
        )
        self.ltm_nodes.append(LtmNode(self.graph, ltm, clock=self.clock))
        return ltm

    def router(self, dependencies: Sequence[params.Depends] | None = None) -> APIRouter:
        deps = [*(dependencies or ()), Depends(standby_guard(lambda: self.role))]
        router = make_fleet_router(
            self.ctm, clock=self.clock, dependencies=deps, on_change=self.node.poke
        )
        router.include_router(make_patrol_router(self.central))

        @router.get("/central", response_model=CentralRoleInfo, response_model_exclude_unset=True)
        async def central_role() -> dict[str, Any]:
            """Who holds the fleet's central role, as this console sees it (``role``:
            ``central``, ``standby``, or ``only`` for a console on no bus)."""
            if self.role is None:
                return {"role": "only", "central": None}
            return self.role.info()

        return router

    async def start(self) -> None:
        self.graph.advertise_service(PATROL_SERVICE, PATROL_SERVICE_TYPE, self._patrol_service)
        await self.node.start()
        self._task = asyncio.create_task(self._run(), name="ltm-nodes")

    async def _patrol_service(self, args: dict[str, Any]) -> dict[str, Any]:
        """``/fleet/patrol``: the Central patrol for a vehicle process's dialog ("start the
        patrol"), as the console's button starts it here."""
        op = args.get("op")
        if op == "start":
            threshold = float(args.get("threshold", 0.30))
            if not 0.0 < threshold < 1.0:
                raise ValueError(f"threshold must be between 0 and 1, not {threshold}")
            try:
                handoff = Handoff(args.get("handoff", Handoff.PREDICTIVE.value))
            except ValueError:
                raise ValueError(
                    f"handoff must be reactive or predictive, not {args.get('handoff')!r}"
                ) from None
            reply = self.central.start(threshold, handoff)
        elif op == "stop":
            reply = self.central.stop()
        elif op == "pause":
            reply = self.central.pause()
        elif op == "resume":
            reply = self.central.resume()
        else:
            raise ValueError(f"unknown op {op!r} (start, stop, pause, resume)")
        return {"ok": reply.ok, "text": reply.text, "mission": reply.mission}

    async def _run(self) -> None:
        while True:
            now = self.clock()
            for n in self.ltm_nodes:
                n.step(now)
            await asyncio.sleep(self.period_s)

    async def leave_bus(self) -> None:
        """Leave the election (releasing the role if held), before the bus closes."""
        if self.role is not None:
            await self.role.stop()
            self.role = None

    async def stop(self) -> None:
        await self.leave_bus()
        self.graph.unadvertise_service(PATROL_SERVICE)
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        await self.node.stop()
        for n in self.ltm_nodes:
            n.close()
