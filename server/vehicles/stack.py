"""One drone's flight stack, as the server sees it, and the one place that builds it.

:class:`DroneStack` is what the REST routes and the console ask of a drone (telemetry, direct
actions, the latest JPEG, ground truth); :func:`build_drone_stack` builds one alike for a drone
in the web process and in a vehicle process (server.vehicles.host);
:class:`~server.vehicles.remote.RemoteDroneStack` answers the same for a drone in its own
process.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, fields, is_dataclass
from typing import TYPE_CHECKING, Any

from drone.ardrone.driver import ARDroneDriver
from drone.ardrone.protocol import DriverConfig
from drone.ardrone.vehicle import ARDroneVehicle
from drone.camera import CameraModel
from drone.commands import DirectAction
from drone.sim.drone import SimConfig
from drone.sim.server import SimServer, sim_endpoint
from drone.sim.world import World
from drone.supervisor import Supervisor, keep_away_of, supervise
from drone.vehicle import Vehicle
from server.graph import Graph
from server.nodes.mavros_node import MavrosNode
from server.nodes.vehicle_node import VehicleNode
from server.settings import Settings
from server.tasks.manager import TaskManager
from server.timewarp import guard_s
from server.vehicles.mavlink_stack import is_mavlink, start_mavlink
from server.vehicles.stops import StopLedger

if TYPE_CHECKING:  # the captioner is the console's: a vehicle process never loads it
    from server.captioner.grounding import SeenMarker


@dataclass
class DroneStack:
    """One drone as the server sees it."""

    name: str
    prefix: str  # "" for a single drone, "/uav2" in a fleet
    vehicle: Vehicle
    driver: ARDroneDriver
    sim: SimServer | None = None
    tasks: TaskManager | None = None
    node: VehicleNode | None = None
    supervisor: Supervisor | None = None  # the safety monitors (ANS), acting on this drone
    # stop ids run and superseded: each stop runs once, whichever road brings it first
    stops: StopLedger = field(default_factory=StopLedger)

    def link_ok(self) -> bool:
        return bool(self.vehicle.snapshot().link_ok)

    def telemetry(self) -> dict[str, Any]:
        """JSON-ready telemetry of ``GET /api/v1/drones/{id}``."""
        out: dict[str, Any] = to_json_ready(self.vehicle.snapshot())
        out["name"] = self.name
        out["simulated"] = self.sim is not None
        if self.tasks is not None:
            out["task"] = to_json_ready(self.tasks.status)
        return out

    def direct(self, action: str) -> str:
        """Direct control from a button or REST; land and emergency bypass every queue.

        Raises:
            ValueError: ``action`` is not a :class:`~drone.commands.DirectAction` (nothing is
                sent: the vehicle is driven from this fixed table, never by the name given).
        """
        which = DirectAction(action)
        if which in (DirectAction.LAND, DirectAction.EMERGENCY) and self.tasks is not None:
            self.tasks.preempt(which.value)
            return f"{which} sent"
        if which is DirectAction.HOVER and self.tasks is not None:
            self.tasks.cancel("hover requested")
        vehicle = self.vehicle
        send = {
            DirectAction.TAKEOFF: vehicle.takeoff,
            DirectAction.LAND: vehicle.land,
            DirectAction.HOVER: vehicle.hover,
            DirectAction.EMERGENCY: vehicle.emergency,
            DirectAction.RESET: vehicle.reset,
        }[which]
        send()
        return f"{which} sent"

    def seen_markers(self) -> list[SeenMarker]:
        """The markers the detector sees now (grounding a caption's "marker N on the left")."""
        from server.captioner.grounding import seen_markers

        return seen_markers(self.vehicle.snapshot())

    def latest_jpeg(self) -> tuple[int, bytes | None]:
        """(frame counter, JPEG with the tracking overlay): the one the vehicle node encodes
        for ``/ardrone/image_raw/compressed``, so MJPEG viewers cost no second encode."""
        return self.node.latest_jpeg if self.node is not None else (-1, None)

    def truth(self) -> dict[str, Any]:
        assert self.sim is not None
        out: dict[str, Any] = to_json_ready(self.sim.truth)
        out["name"] = self.name
        return out

    def inject_fault(self, body: Any) -> None:
        assert self.sim is not None
        params: dict[str, float] = {}
        if body.duration_s is not None:
            params["duration_s"] = body.duration_s
        if body.battery_pct is not None:
            params["battery_pct"] = body.battery_pct
        if body.drain_pct_s is not None:
            params["drain_pct_s"] = body.drain_pct_s
        if body.wind_mps is not None:
            params["wind_x"], params["wind_y"] = body.wind_mps
        self.sim.inject_fault(body.kind, **params)


async def build_drone_stack(
    name: str,
    prefix: str,
    index: int,
    kind: str,
    world: World,
    settings: Settings,
    graph: Graph,
    audit: Any,
    *,
    own_process: bool = False,
) -> DroneStack:
    """One drone's flight stack, built alike in the web process (inline) and in a vehicle
    process: its simulator for ``sim`` / ``sim-mavlink`` (started) or its link, the driver and
    vehicle (started), the task manager, its supervisor and its graph node (not yet started;
    the supervisor is stepped by whoever runs the drone: ``supervisor.run``). ``kind`` is the
    drone's ``--drone`` entry; ``audit`` (an AuditLog) gets the node's jog and topic rows;
    ``own_process``: built by a vehicle process (the AR.Drone's control thread then holds the
    GIL while it spins and asks for ``control_rt_priority``).

    Raises:
        SettingsError: ``kind`` looks like a MAVLink connection string but is not one.
    """
    s = settings
    node_class: type[VehicleNode]
    if is_mavlink(kind):
        parts = await start_mavlink(name, kind, index, world, s)
        vehicle: Vehicle = parts.vehicle
        driver: Any = parts.driver
        sim: Any = parts.sim
        node_class, idle_search = MavrosNode, False  # the autopilot flies; no camera to search
    else:
        sim = None
        if kind == "sim":
            addr, ports = sim_endpoint(index, s.sim_base_addr)
            sim = SimServer(
                addr,
                world,
                ports=ports,
                speed=s.sim_speed,
                seed=s.seed + index,
                config=SimConfig(flight_time_s=s.flight_time_s),
            )
            await sim.start()
            driver = ARDroneDriver(
                addr,
                at_port=ports.at,
                navdata_port=ports.navdata,
                video_port=ports.video,
                config=DriverConfig(link_timeout_s=guard_s(s.link_timeout_s)),
                video=s.camera,
            )
        else:
            driver = ARDroneDriver(
                kind, config=DriverConfig(link_timeout_s=guard_s(s.link_timeout_s)), video=s.camera
            )
        await driver.start()
        ardrone = ARDroneVehicle(
            name, world, camera=CameraModel(), link_timeout_s=guard_s(s.link_timeout_s)
        )
        if sim is not None and not s.camera:
            # no camera, no marker to find its heading by: a simulated drone starts from its
            # true start pose, a surveyed home station (as drone.lockstep's known_start)
            t = sim.truth
            ardrone.ekf.reset(ardrone.clock.now(), t.x, t.y, t.z, t.yaw_rad)
        await ardrone.start(
            driver,
            own_process=own_process,
            realtime_priority=s.control_rt_priority if own_process else 0,
        )
        vehicle = ardrone
        node_class, idle_search = VehicleNode, True
    # People: where the simulator has them (its person tracker); a real drone has no tracker
    # here, so only its own sensors and the operator keep it from people.
    keep = keep_away_of(world, sim.sim.people) if isinstance(sim, SimServer) else None
    tasks = TaskManager(
        vehicle,
        world,
        vehicle.clock,
        search_after_s=s.search_after_s,
        idle_search=idle_search,
        keep_away=keep,
    )
    node = node_class(
        graph,
        vehicle,
        tasks,
        name,
        prefix,
        heartbeat_timeout_s=guard_s(s.heartbeat_timeout_s),
        audit=audit,
        command_deadline_s=s.command_deadline_s,
    )
    supervisor = supervise(vehicle, tasks, world, s, keep_away=keep)
    return DroneStack(name, prefix, vehicle, driver, sim, tasks, node, supervisor=supervisor)


def to_json_ready(value: Any) -> Any:
    """Dataclasses, enums, tuples and floats as JSON values (enums by name, NaN/inf as null)."""
    if is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_json_ready(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, dict):
        return {str(k): to_json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_json_ready(v) for v in value]
    if isinstance(value, enum.Enum):
        return value.name
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value
