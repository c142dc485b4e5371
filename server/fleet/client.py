"""``uav-console vehicle``: one drone's LTM joining a central server as a rosbridge v2 client.

``BridgeClientCore`` is the sans-I/O part (text frames in, text frames out): on connect it
advertises ``/NAME/fleet/ltm_status`` (std_msgs/String) and the service
``/NAME/fleet/flight_plan``, subscribes to ``/fleet/status`` (the CTM's heartbeat); it answers
``call_service`` for the plan service with the LTM's decision (a malformed plan gets
``result: false`` and the reason), and turns statuses into ``publish`` frames.
``VehicleClient`` is the asyncio driver (``websockets``): it keeps the LTM stepping whether or
not the central server is reachable (so the LTM's own "CTM silent → fly home" rule works) and
reconnects with exponential backoff (0.5 s doubling to 5 s) through
:class:`~server.vehicles.central_connection.CentralConnection`.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from server.fleet.errors import ClientError, FleetError
from server.fleet.ltm import LocalTaskManager
from server.fleet.messages import (
    FLEET_TOPIC,
    FLEET_TYPE,
    PLAN_SERVICE,
    PLAN_SERVICE_TYPE,
    STATUS_TOPIC,
    STATUS_TYPE,
    LtmStatus,
)
from server.http.tls import TLSError
from server.settings import Settings
from server.vehicles.central_connection import CentralConnection, CentralServer

log = logging.getLogger(__name__)


class BridgeClientCore:
    """Sans-I/O rosbridge client logic of one LTM (see the module docstring)."""

    def __init__(self, ltm: LocalTaskManager) -> None:
        self.ltm = ltm
        self.status_topic = f"/{ltm.name}/{STATUS_TOPIC}"
        self.plan_service = f"/{ltm.name}/{PLAN_SERVICE}"
        self.plans = 0
        self.heartbeats = 0
        self.errors: list[str] = []  # status messages from the server (refusals)

    def hello(self) -> list[str]:
        """Frames to send right after (re)connecting."""
        ops = [
            {"op": "advertise", "topic": self.status_topic, "type": STATUS_TYPE},
            {"op": "advertise_service", "service": self.plan_service, "type": PLAN_SERVICE_TYPE},
            {"op": "subscribe", "topic": FLEET_TOPIC, "type": FLEET_TYPE, "throttle_rate": 0},
        ]
        return [json.dumps(o) for o in ops]

    def status_frame(self, st: LtmStatus) -> str:
        msg = {"data": json.dumps(st.to_dict())}
        return json.dumps({"op": "publish", "topic": self.status_topic, "msg": msg})

    def receive(self, text: str, now: float) -> list[str]:
        """Handle one frame from the server; returns the frames to send back."""
        try:
            obj = json.loads(text)
        except ValueError:
            self.errors.append(f"unparsable frame: {text[:80]!r}")
            return []
        if not isinstance(obj, dict):
            return []
        op = obj.get("op")
        if op == "publish" and obj.get("topic") == FLEET_TOPIC:
            self.heartbeats += 1
            self.ltm.heard_ctm(now)
        elif op == "call_service":
            return [self._answer(obj, now)]
        elif op == "status" and obj.get("level") in ("error", "warning"):
            self.errors.append(str(obj.get("msg")))
            log.warning("central server: %s", obj.get("msg"))
        return []

    def _answer(self, obj: dict[str, Any], now: float) -> str:
        service = obj.get("service")
        head: dict[str, Any] = {"op": "service_response", "service": service}
        if obj.get("id") is not None:
            head["id"] = obj["id"]
        if service != self.plan_service:
            return json.dumps({**head, "result": False, "values": f"no service {service}"})
        args = obj.get("args") or {}
        try:
            values = self.ltm.apply_plan_dict(args, now)
        except FleetError as exc:
            return json.dumps({**head, "result": False, "values": str(exc)})
        self.plans += 1
        return json.dumps({**head, "result": True, "values": values})


class VehicleClient:
    """Asyncio driver: connect, say hello, pump frames, step the LTM, reconnect.

    Args:
        url: ``ws://HOST:8000/rosbridge``.
        ltm: the local task manager (its task manager is stepped by ``step_tasks``).
        token: pilot token (``Authorization: Bearer``).
        clock: the LTM's clock.
        step_tasks: called every period before the LTM (real vehicles: ``tm.step``).
    """

    def __init__(
        self,
        url: str,
        ltm: LocalTaskManager,
        *,
        token: str | None = None,
        clock: Callable[[], float] = time.monotonic,
        period_s: float = 0.05,
        step_tasks: Callable[[float], Any] | None = None,
        backoff_s: tuple[float, float] = (0.5, 5.0),
        ca_file: Path | None = None,
        fingerprint: str | None = None,
    ) -> None:
        # wss://: verify the central's certificate with a CA file or a pinned
        # SHA-256 fingerprint; a wrong certificate stops the client with the reason.
        self.conn = CentralConnection(
            CentralServer(url, token, ca_file, fingerprint),
            error=ClientError,
            name=ltm.name,
            log=log,
            backoff_s=backoff_s,
        )
        self.url = url
        self.core = BridgeClientCore(ltm)
        self.ltm = ltm
        self.clock = clock
        self.period_s = period_s
        self.step_tasks = step_tasks

    @property
    def connects(self) -> int:
        """How many times the client has joined the central server."""
        return self.conn.connects

    async def run(self, stop: asyncio.Event | None = None) -> None:
        """Run until ``stop`` is set (or forever)."""
        stop = stop or asyncio.Event()
        stepper = asyncio.create_task(self._step_loop(stop))
        try:
            await self.conn.run(stop, hello=self.core.hello, session=lambda ws: [self._read(ws)])
        finally:
            stepper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await stepper

    async def _read(self, ws: Any) -> None:
        async for text in ws:
            if isinstance(text, bytes):
                continue
            for out in self.core.receive(text, self.clock()):
                await ws.send(out)

    async def _step_loop(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            now = self.clock()
            if self.step_tasks is not None:
                self.step_tasks(now)
            st = self.ltm.step(now)
            ws = self.conn.ws
            if st is not None and ws is not None:
                with contextlib.suppress(Exception):  # a dropped connection: the reader notices
                    await ws.send(self.core.status_frame(st))
            await asyncio.sleep(self.period_s)

    async def drop(self, hold_s: float = 0.0) -> None:
        """Close the current connection and stay away ``hold_s`` before reconnecting (a network
        outage, for tests and drills)."""
        await self.conn.drop(hold_s)


def vehicle_main(args: argparse.Namespace, settings: Settings) -> int:
    """``uav-console vehicle --central URL --name NAME [--drone sim|IP] [--world W]``;
    ``settings`` read once by the command (the pilot token is ``settings.token``)."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    try:
        tls = (getattr(args, "ca", None), getattr(args, "fingerprint", None))
        asyncio.run(_vehicle(args.central, args.name, settings, tls))
    except (FleetError, TLSError) as exc:
        print(f"uav-console vehicle: {exc}", file=__import__("sys").stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


async def _vehicle(
    central: str,
    name: str,
    settings: Settings,
    tls: tuple[Path | None, str | None] = (None, None),
) -> None:
    from drone.ardrone.driver import ARDroneDriver
    from drone.ardrone.vehicle import ARDroneVehicle
    from drone.control.clock import MonotonicClock
    from drone.sim.server import SimServer, sim_endpoint
    from drone.sim.world import load_world
    from server.fleet.geo import Enu, origin_of
    from server.tasks.manager import TaskManager

    drone, token = settings.drone, settings.token
    world = load_world(settings.world)
    digits = "".join(c for c in name if c.isdigit())
    index = max(0, int(digits) - 1) if digits else 0
    stations = world.stations or ()
    if stations:
        p = stations[min(index, len(stations) - 1)].position
        station = Enu(float(p[0]), float(p[1]), float(p[2]))
    else:
        station = Enu(world.start.x, world.start.y, 0.0)
    from server.vehicles.mavlink_stack import is_mavlink

    if is_mavlink(drone):  # a PX4/ArduPilot drone: tcp:…, udpin:…, sim-mavlink
        await _mavlink_vehicle(central, name, index, world, station, settings)
        return
    sim = None
    if drone == "sim":
        addr, ports = sim_endpoint(0, settings.sim_base_addr)
        sim = SimServer(addr, world, ports=ports, seed=index + 1)
        await sim.start()
        driver = ARDroneDriver(
            addr, at_port=ports.at, navdata_port=ports.navdata, video_port=ports.video
        )
    else:
        driver = ARDroneDriver(drone)
    await driver.start()
    clock = MonotonicClock()
    vehicle = ARDroneVehicle(name, world, clock=clock)
    vehicle.ekf.reset(clock.now(), station.x, station.y, 0.0, world.start.yaw_rad)
    await vehicle.start(driver)
    tm = TaskManager(vehicle, world, clock)
    ltm = LocalTaskManager(name, vehicle, tm, station, origin=origin_of(world))
    client = VehicleClient(
        central,
        ltm,
        token=token,
        clock=clock.now,
        step_tasks=tm.step,
        ca_file=tls[0],
        fingerprint=tls[1],
    )
    try:
        await client.run()
    finally:
        await vehicle.stop(land=True)
        await driver.stop()
        if sim is not None:
            await sim.stop()


async def _mavlink_vehicle(
    central: str, name: str, index: int, world: Any, station: Any, settings: Settings
) -> None:
    """``vehicle --drone tcp:…``: a MAVLink drone's stack joining the central server."""
    from server.fleet.geo import origin_of
    from server.tasks.manager import TaskManager
    from server.vehicles.mavlink_stack import start_mavlink

    token = settings.token
    parts = await start_mavlink(name, settings.drone, index, world, settings)
    vehicle = parts.vehicle
    tm = TaskManager(vehicle, world, vehicle.clock)
    ltm = LocalTaskManager(name, vehicle, tm, station, origin=origin_of(world))
    client = VehicleClient(central, ltm, token=token, clock=vehicle.clock.now, step_tasks=tm.step)
    try:
        await client.run()
    finally:
        await vehicle.stop(land=True)
        await parts.driver.stop()
        if parts.sim is not None:
            await parts.sim.stop()
