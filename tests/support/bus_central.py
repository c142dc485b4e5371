"""A central console's fleet on a bus, in the test process: the console's Zenoh router
(:class:`~drone.bus.console.ConsoleBus`, its credentials and access control), the fleet service
with its central role on that router (``serve``'s composition, ``server.runtime``), and the
fleet's REST doors (``/api/v1/missions``, ``/fleet``, ``/patrol``, ``/central``) served by a real
uvicorn in a thread. Vehicles join the router as ``serve``'s do, each with its own credential."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi import FastAPI

from drone.bus.console import ConsoleBus, VehicleCredential
from server.fleet.ctm import CentralTaskManager
from server.fleet.failover import CentralRole
from server.fleet.service import FleetService
from server.graph import Graph
from tests.support.loopback import bus_endpoint
from tests.support.servers import threaded_server

FLEET = "default"
CONSOLE = "central"


@dataclass
class BusCentral:
    """A running central (see the module docstring)."""

    url: str  # the REST doors' base, ``http://127.0.0.1:PORT``
    router: ConsoleBus
    service: FleetService
    graph: Graph

    @property
    def endpoint(self) -> str:
        """Where the router listens (``tcp/127.0.0.1:PORT``)."""
        return self.router.listen[0]

    @property
    def ctm(self) -> CentralTaskManager:
        return self.service.ctm

    @property
    def role(self) -> CentralRole:
        assert self.service.role is not None
        return self.service.role

    def credential(self, name: str) -> VehicleCredential:
        """Vehicle ``name``'s credential on this bus (its password is its vehicle key)."""
        return self.router.vehicle_credential(name)


@contextlib.contextmanager
def bus_central(
    tmp: Path,
    world: Any,
    vehicles: Iterable[str] = (),
    keys: Mapping[str, str] | None = None,
) -> Iterator[BusCentral]:
    """A central on a router of its own in ``tmp/bus``: ``vehicles`` get a credential it makes,
    ``keys`` (name → vehicle key, ``uav-console vehicle-key``) are the passwords of vehicles
    from elsewhere, as ``serve`` takes its data directory's vehicle keys."""
    router = ConsoleBus(
        tmp / "bus",
        FLEET,
        list(vehicles),
        name=CONSOLE,
        listen=[bus_endpoint()],
        vehicle_passwords=keys,
    )
    router.start()
    graph = Graph()
    service = FleetService(graph, world)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        graph.bind_loop(asyncio.get_running_loop())
        await service.start()
        await service.join_bus(router.session, FLEET, CONSOLE)
        yield
        await service.stop()

    app = FastAPI(lifespan=lifespan)
    app.include_router(service.router(), prefix="/api/v1")
    try:
        with threaded_server(app) as served:
            yield BusCentral(served.url(), router, service, graph)
    finally:
        router.close()
