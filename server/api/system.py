"""``GET /health`` and ``GET /world``: what the server is and the map the drones fly in."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from server import __version__
from server.api.deps import RoleDep, RuntimeDep
from server.api.models import BusHealth, BusJoin, Health, WorldInfo

router = APIRouter(tags=["system"])


@router.get("/health", response_model=Health)
def health(runtime: RuntimeDep) -> Health:
    """Liveness and the state of each part (no token needed)."""
    links = {name: stack.link_ok() for name, stack in runtime.drones.items()}
    captioner = runtime.captioner_status()
    ok = all(links.values()) and captioner == "ready"
    bus = runtime.vehicles.bus
    return Health(
        status="ok" if ok else "degraded",
        version=__version__,
        drones=links,
        captioner=captioner,
        bus=None
        if bus is None
        else BusHealth(
            endpoints=bus.listen,
            alive=bus.alive(),
            client_config=str(bus.client_file),
            joins=[
                BusJoin(endpoint=j.endpoint, joined=j.joined, since=j.since) for j in bus.joins()
            ],
        ),
    )


@router.get("/world", response_model=WorldInfo, response_model_exclude_unset=True)
def world(runtime: RuntimeDep, _role: RoleDep) -> dict[str, Any]:
    """Markers (id and pose), stations, bounds and GPS origin of the world being flown."""
    return runtime.world.to_dict()
