"""Starting one MAVLink drone for the runtime: simulator (``--drone sim-mavlink``) or a vehicle
at a connection string (``--drone tcp:10.0.0.5:5760``, ``udpin:0.0.0.0:14550`` …), its driver,
:class:`~drone.mavlink.vehicle.MavlinkVehicle`, and :class:`~server.mavros_node.MavrosNode`.

``--drone`` may also list one kind per drone of a fleet, comma-separated
(``--fleet 3 --drone sim,sim-mavlink,sim-mavlink``): a mixed fleet; the last kind repeats.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from drone.mavlink.autopilot import SimAutopilot
from drone.mavlink.client import GcsProtocol
from drone.mavlink.driver import MavlinkDriver, parse_connection
from drone.mavlink.errors import ConnectionStringError
from drone.mavlink.simserver import MavlinkSimServer
from drone.mavlink.vehicle import MavlinkVehicle
from drone.sim.server import sim_endpoint
from server.settings import SettingsError

SIM_MAVLINK = "sim-mavlink"


def drone_kind(spec: str, index: int) -> str:
    """The ``--drone`` entry for drone ``index`` (0-based) of a comma-separated list."""
    parts = [p.strip() for p in spec.split(",") if p.strip()] or ["sim"]
    return parts[min(index, len(parts) - 1)]


MAVLINK_SCHEMES = ("tcp", "tcpout", "udp", "udpin", "udpout")


def is_mavlink(kind: str) -> bool:
    """Whether a ``--drone`` entry names a MAVLink vehicle.

    Raises:
        SettingsError: it looks like a MAVLink connection string but is not a valid one.
    """
    if kind == SIM_MAVLINK:
        return True
    if kind.split(":")[0] in MAVLINK_SCHEMES or kind.startswith("/dev/"):
        try:
            parse_connection(kind)
        except ConnectionStringError as exc:
            raise SettingsError(f"--drone: {exc}") from exc
        return True
    return False


def signing_key(hex_key: str | None) -> bytes | None:
    """``UAVC_MAVLINK_KEY``: 64 hex digits (the 32-byte MAVLink 2 signing secret).

    Raises:
        SettingsError: not 64 hex digits.
    """
    if not hex_key:
        return None
    try:
        key = bytes.fromhex(hex_key)
    except ValueError:
        key = b""
    if len(key) != 32:
        raise SettingsError("UAVC_MAVLINK_KEY must be 64 hex digits (a 32-byte signing secret)")
    return key


@dataclass
class MavlinkParts:
    vehicle: MavlinkVehicle
    driver: MavlinkDriver
    sim: MavlinkSimServer | None


async def start_mavlink(
    name: str, kind: str, index: int, world: Any, settings: Any
) -> MavlinkParts:
    """Start the simulator (for ``sim-mavlink``), the driver, and the vehicle hooked to it."""
    key = signing_key(getattr(settings, "mavlink_key", None))
    sim: MavlinkSimServer | None = None
    if kind == SIM_MAVLINK:
        addr, _ = sim_endpoint(index, settings.sim_base_addr)
        start = None
        stations = getattr(world, "stations", ())
        if index < len(stations):
            p = stations[index].position
            start = (p[0], p[1], world.start.yaw_rad)
        sim = MavlinkSimServer(
            addr,
            SimAutopilot(world, start=start, signing_key=key),
            tcp_port=settings.mavlink_sim_port,
            udp_port=None,
            speed=settings.sim_speed,
        )
        await sim.start()
        connection = f"tcp:{addr}:{sim.tcp_port}"
    else:
        connection = kind
    protocol = GcsProtocol(signing_key=key)
    driver = MavlinkDriver(connection, protocol)
    vehicle = MavlinkVehicle(name, world, protocol)
    await vehicle.start(driver)
    await driver.start()
    return MavlinkParts(vehicle, driver, sim)
