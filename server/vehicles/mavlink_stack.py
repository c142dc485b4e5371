"""Starting one MAVLink drone for the runtime: simulator (``--drone sim-mavlink``) or a vehicle
at a connection string (``--drone tcp:10.0.0.5:5760``, ``udpin:0.0.0.0:14550`` …), its driver,
:class:`~drone.mavlink.vehicle.MavlinkVehicle`, and :class:`~server.nodes.mavros_node.MavrosNode`;
and ``uav-console sim --protocol mavlink`` (:func:`sim_main`).

``--drone`` may also list one kind per drone of a fleet, comma-separated
(``--fleet 3 --drone sim,sim-mavlink,sim-mavlink``): a mixed fleet; the last kind repeats.

Signing: a simulated PX4 always signs, with ``UAVC_MAVLINK_KEY`` when set, else with the key of
the data directory (``drone.mavlink.signing``: made on first use, shared by ``serve`` and
``sim``), and the console's driver signs with the same key. A vehicle at a connection string
is signed only when ``UAVC_MAVLINK_KEY`` is set (a real PX4 or ArduPilot must be given the key
first).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drone.mavlink import signing
from drone.mavlink.driver import MavlinkDriver, parse_connection
from drone.mavlink.errors import ConnectionStringError, MavlinkError
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.simserver import MavlinkSimServer, run_mavlink_sim
from drone.mavlink.vehicle import MavlinkVehicle
from drone.sim.server import sim_endpoint
from server.settings import Settings, SettingsError

log = logging.getLogger(__name__)
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


def sim_signing_key(settings: Any) -> tuple[bytes, Path | None]:
    """The key a simulated PX4 signs with, and the passphrase file it comes from (None: from
    ``UAVC_MAVLINK_KEY``).

    Raises:
        SettingsError: a bad ``UAVC_MAVLINK_KEY``, or a passphrase file that cannot be made,
            read or trusted.
    """
    key = signing_key(getattr(settings, "mavlink_key", None))
    if key is not None:
        return key, None
    try:
        return signing.load_or_create(Path(settings.data_dir))
    except MavlinkError as exc:
        raise SettingsError(str(exc)) from exc


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
        key, key_file = sim_signing_key(settings)
        log.info("%s: simulated PX4 signs with %s", name, key_file or "UAVC_MAVLINK_KEY")
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


def sim_main(args: argparse.Namespace) -> int:
    """``uav-console sim --protocol mavlink [--addr A] [--world W] [--speed S] [--insecure]
    [--print-key] [--data-dir D]``.

    Raises:
        SettingsError: a bad key, world or address, or ``--insecure`` off loopback.
    """
    from drone.sim.errors import SimConfigError
    from drone.sim.world import WorldError, load_world

    overrides = {"data_dir": args.data_dir} if args.data_dir else {}
    settings = Settings.from_env(**overrides)
    addr = args.addr or "127.0.0.9"
    if args.print_key:
        print(sim_signing_key(settings)[0].hex())
        return 0
    key: bytes | None = None
    key_file: Path | None = None
    if not args.insecure:
        key, key_file = sim_signing_key(settings)
    try:
        world = load_world(args.world)
        asyncio.run(
            run_mavlink_sim(
                addr,
                world,
                speed=args.speed,
                signing_key=key,
                key_file=key_file,
                insecure=args.insecure,
            )
        )
    except (MavlinkError, WorldError, SimConfigError) as exc:
        raise SettingsError(str(exc)) from exc
    except OSError as exc:  # the address is not ours, or the port is taken
        raise SettingsError(f"cannot serve MAVLink on {addr}: {exc}") from exc
    return 0
