"""The web process's side of vehicle processes: the link endpoint, discovery, supervision.

- ``/vehicle-link``: a rosbridge v2 WebSocket for vehicles only. It takes the pilot token and no
  browser (a request with ``Origin`` is refused); a vehicle may publish its drone's topics
  without holding the pilot lease (it reports, it does not command) and may provide services.
- Discovery: every ``/NAME/vehicle/info`` on the graph becomes a drone of the runtime
  (:class:`~server.vehicles.remote.RemoteDroneStack` + :class:`RemoteDialog`), whether
  ``serve`` spawned the vehicle or it joined from another host (``uav-console vehicle``).
- Heartbeat: ``/vehicles/heartbeat`` at 10 Hz, so a vehicle can tell a stalled server.
- Supervision (``--vehicles process``, ``serve``'s default): one ``uav-console vehicle`` child
  per drone, AR.Drone or MAVLink, each given its own ``--drone`` entry (a simulator, AR.Drone
  or PX4, is started and owned by its vehicle); when one exits (a crash, ``kill -9``) the
  console is told on ``/console/reply`` (level ``alert``) and the child is started again
  (backoff 0.5 s doubling to 5 s, reset after 30 s up).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import signal
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import APIRouter, WebSocket

from server.mavlink_stack import SIM_MAVLINK, drone_kind
from server.msgs import header
from server.rosbridge.context import BridgeContext
from server.rosbridge.endpoint import serve_rosbridge
from server.security import Role, Security
from server.settings import Settings, SettingsError
from server.vehicles import names

if TYPE_CHECKING:
    from server.runtime import Runtime

log = logging.getLogger("uav_console")

RESTART_BACKOFF_S = (0.5, 5.0)
STABLE_AFTER_S = 30.0
DISCOVER_EVERY = 5  # heartbeat periods


def pid_dir_of(settings: Settings) -> Path:
    """Where vehicle processes leave their pid (``NAME.pid``) while they run."""
    return names.pid_dir(settings.data_dir, settings.port)


class VehicleLinkSecurity(Security):
    """Security of ``/vehicle-link``: pilot token only, no browsers, no lease to report."""

    def role_for(self, token: str | None) -> Role | None:
        role = self.tokens.role_for(token)
        return role if role is Role.PILOT else None

    def origin_allowed(self, origin: str | None, host_header: str | None) -> bool:
        return origin is None

    def needs_lease(self, service_or_topic: str, *, service: bool) -> bool:
        return False

    # Explicit, so tightening what browser clients may publish (e.g. ``/console/*``) never
    # silences a vehicle's own replies, state and telemetry.
    def can_publish(self, role: Role | None, topic: str) -> bool:
        return role is Role.PILOT

    def can_call(self, role: Role | None, service: str) -> bool:
        return role is Role.PILOT


# What a vehicle process needs of the server's settings (an allowlist: a setting added later
# for the web process never reaches, or breaks, a vehicle).
CHILD_SETTINGS = (
    "host",
    "port",
    "drone",
    "world",
    "seed",
    "sim_base_addr",
    "sim_speed",
    "mavlink_sim_port",
    "mavlink_key",
    "allow_origins",
    "data_dir",
    "grammar_dir",
    "model_dir",
    "heartbeat_timeout_s",
    "link_timeout_s",
    "confidence_threshold",
    "confirm_floor",
    "battery_low_pct",
    "battery_critical_pct",
    "altitude_ceiling_m",
    "ans_period_s",
    "search_after_s",
    "central_loss_land_s",
    "vehicle_nice",
    "control_rt_priority",
    "vehicle_rt_priority",
)


def child_env(settings: Settings, token: str) -> dict[str, str]:
    """The environment of a vehicle child: ours plus the settings it needs as ``UAVC_*``."""
    env = dict(os.environ)
    for name in CHILD_SETTINGS:
        value = getattr(settings, name, None)
        if value is None:
            continue
        if isinstance(value, tuple):
            value = ",".join(str(v) for v in value)
        env[f"UAVC_{name.upper()}"] = str(value)
    env["UAVC_TOKEN"] = token
    env["PYTHONUNBUFFERED"] = "1"
    return env


class VehicleProcess:
    """One supervised ``uav-console vehicle``: our child, or one adopted from a previous
    ``serve`` that crashed (then watched by its pid, since only a parent can ``wait`` for it)."""

    def __init__(self, argv: list[str], env: dict[str, str], name: str) -> None:
        self.argv = argv
        self.env = env
        self.name = name
        self.proc: asyncio.subprocess.Process | None = None
        self.adopted: int | None = None
        self.starts = 0
        self.exits: list[int] = []
        self.started_at = 0.0

    async def spawn(self) -> None:
        self.adopted = None
        self.proc = await asyncio.create_subprocess_exec(
            *self.argv, env=self.env, stdin=asyncio.subprocess.DEVNULL
        )
        self.starts += 1
        self.started_at = time.monotonic()

    def adopt(self, pid: int) -> None:
        self.proc, self.adopted = None, pid
        self.started_at = time.monotonic()

    async def wait(self) -> int:
        """The exit status (an adopted process: -9 if gone, its status is not ours to read)."""
        if self.proc is not None:
            return await self.proc.wait()
        while self.adopted is not None and _alive(self.adopted):
            await asyncio.sleep(0.2)
        return -9

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else self.adopted


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class VehicleCentral:
    """See the module docstring; owned by :class:`~server.runtime.Runtime`."""

    def __init__(self, runtime: Runtime) -> None:
        self.runtime = runtime
        s = runtime.settings
        if s.vehicles not in ("inline", "process"):
            raise SettingsError(f"vehicles must be inline or process, not {s.vehicles!r}")
        self.ctx = BridgeContext(runtime.graph, VehicleLinkSecurity(s, runtime.tokens), s)
        self.processes: dict[str, VehicleProcess] = {}
        self.alerts: list[str] = []
        self._tasks: list[asyncio.Task[Any]] = []
        self._stopping = False
        self._recording_sent: str | None = None
        self._utterances: Any = None

    def router(self) -> APIRouter:
        router = APIRouter()

        async def link(websocket: WebSocket) -> None:
            await serve_rosbridge(websocket, self.ctx)

        router.add_api_websocket_route(names.LINK_PATH, link)
        return router

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        g = self.runtime.graph
        g.advertise(names.HEARTBEAT, names.STRING)
        g.advertise("/console/reply", "uav_console/Reply")
        g.advertise(names.RECORDING, names.STRING, latch=True)
        # Subscribed before any vehicle link: called before the link passes the utterance on.
        self._utterances = g.subscribe(
            "/console/utterance", lambda _msg: self.touch_recording(), type="uav_console/Utterance"
        )
        self._tasks.append(asyncio.create_task(self._beat(), name="vehicles-heartbeat"))

    def flight_stacks(self) -> str:
        """Where each drone's flight stack runs, for ``serve``'s start-up lines."""
        from server.vehicles.remote import RemoteDroneStack

        drones = self.runtime.drones
        remote = [n for n, d in drones.items() if isinstance(d, RemoteDroneStack)]
        local = [n for n in drones if n not in remote]
        return flight_stacks_line(remote, local)

    async def spawn(self, count: int) -> None:
        """Register drones ``uav1`` … ``uavN`` now; start (or adopt) their vehicle processes in
        the background, once the server accepts connections (see :meth:`_orphans`)."""
        s = self.runtime.settings
        host = "127.0.0.1" if s.host in ("0.0.0.0", "::", "") else s.host
        tls = self.runtime.tls  # set by `serve` before the lifespan starts us
        url = f"{'wss' if tls else 'ws'}://{host}:{s.port}{names.LINK_PATH}"
        # The safety port listens where the console does (a phone on the LAN reaches both),
        # over HTTPS with the console's certificate when the console speaks it.
        safety = ["--safety-host", s.host]
        if tls is not None:
            safety += ["--safety-cert", str(tls.cert), "--safety-key", str(tls.key)]
        env = child_env(s, self.runtime.tokens.pilot_token)
        for index in range(count):
            name = f"uav{index + 1}"
            prefix = "" if count == 1 else f"/{name}"
            argv = [sys.executable, "-m", "server", "vehicle", "--central", url, "--name", name]
            kind = drone_kind(s.drone, index)  # its own entry of a comma-separated --drone
            argv += ["--prefix", prefix, "--index", str(index), "--drone", kind]
            argv += ["--world", s.world, *safety, "--parent-pid", str(os.getpid())]
            if tls is not None:  # our own certificate, pinned (whatever names it carries)
                argv += ["--fingerprint", tls.fingerprint]
            self.processes[name] = VehicleProcess(argv, env, name)
            self._register(name, prefix, simulated=kind in ("sim", SIM_MAVLINK))
            self._expect(name)
        self._tasks.append(asyncio.create_task(self._launch(), name="vehicles-launch"))

    async def _launch(self) -> None:
        orphans = await self._orphans(set(self.processes))
        for name, vp in self.processes.items():
            if name in orphans:
                vp.adopt(orphans[name])
                log.warning("%s: adopted the running vehicle process %d", name, orphans[name])
            else:
                await vp.spawn()
            self._tasks.append(asyncio.create_task(self._supervise(vp), name=f"supervise:{name}"))

    async def _orphans(self, names_: set[str], wait_s: float = 4.0) -> dict[str, int]:
        """Vehicles left flying by a ``serve`` that crashed (their pid files in the data
        directory name live processes): they reconnect within their backoff (at most 2 s) and
        announce their pid; wait ``wait_s`` for them, then adopt them. No pid file: no wait."""
        pid_dir = pid_dir_of(self.runtime.settings)
        expected = set()
        for name in names_:
            with contextlib.suppress(OSError, ValueError):
                if _alive(int((pid_dir / f"{name}.pid").read_text())):
                    expected.add(name)
        if not expected:
            return {}
        names_ = expected
        found: dict[str, int] = {}
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and set(found) != names_:
            await asyncio.sleep(0.1)
            for name in names_ - set(found):
                last = self.runtime.graph.latched(names.info_topic(name))
                if last is None:
                    continue
                with contextlib.suppress(ValueError, KeyError, TypeError):
                    pid = int(json.loads(str(last.get("data", "")))["pid"])
                    if _alive(pid):
                        found[name] = pid
        return found

    def touch_recording(self) -> None:
        """An operator's command is on its way to a vehicle: open (or keep open) the flight
        recording, as an in-process dialog's audit row does, and tell the vehicles its id
        first, so the rows they write for the command carry it."""
        from server.vehicles.remote import RemoteDroneStack

        rec = self.runtime.recorder
        if rec is None or not any(
            isinstance(d, RemoteDroneStack) for d in self.runtime.drones.values()
        ):
            return
        self._publish_recording(rec.touch())

    def _publish_recording(self, recording: str) -> None:
        if recording != self._recording_sent:
            self._recording_sent = recording
            self.runtime.graph.publish(names.RECORDING, {"data": recording})

    async def stop(self) -> None:
        if self._utterances is not None:
            self._utterances.close()
        self._stopping = True
        for t in self._tasks:
            t.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        for vp in self.processes.values():
            await _terminate(vp)

    # ------------------------------------------------------------------ drones
    def _register(self, name: str, prefix: str, *, simulated: bool) -> None:
        from server.vehicles.remote import RemoteDialog, RemoteDroneStack

        rt = self.runtime
        if name in rt.drones:
            return
        stack = RemoteDroneStack(rt.graph, name, prefix, simulated=simulated)
        stack.touch_recording = self.touch_recording
        rt.drones[name] = stack
        rt.dialogs[name] = RemoteDialog(stack)
        # Listings (REST, fleet status, the console's selector) follow the names, not the
        # order in which the vehicles joined.
        for table in (rt.drones, rt.dialogs):
            ordered = sorted(table.items(), key=lambda kv: names.drone_order(kv[0]))
            table.clear()
            table.update(ordered)
        log.info("vehicle %s registered (prefix %r)", name, prefix)

    def _expect(self, name: str) -> None:
        """Its process is starting: REST and dialog calls to the drone wait for it to join."""
        from server.vehicles.remote import RemoteDroneStack

        stack = self.runtime.drones.get(name)
        if isinstance(stack, RemoteDroneStack):
            stack.expect()

    def discover(self) -> None:
        """Register every vehicle that announced itself on the graph and is not a drone yet."""
        for topic in self.runtime.graph.topics():
            if not topic.endswith("/vehicle/info"):
                continue
            last = self.runtime.graph.latched(topic)
            if last is None:
                continue
            try:
                info = json.loads(str(last.get("data", "")))
                name, prefix = str(info["name"]), str(info.get("prefix", f"/{info['name']}"))
            except (ValueError, KeyError, TypeError):
                continue
            if name not in self.runtime.drones:
                self._register(name, prefix, simulated=bool(info.get("simulated", True)))

    async def _beat(self) -> None:
        n = 0
        while True:
            self.runtime.graph.publish(names.HEARTBEAT, {"data": str(n)})
            self._publish_recording(self.runtime.recording_id() or "")
            if n % DISCOVER_EVERY == 0:
                try:
                    self.discover()
                except Exception:
                    log.exception("vehicle discovery failed")
            n += 1
            await asyncio.sleep(names.HEARTBEAT_PERIOD_S)

    def alert(self, text: str) -> None:
        """Tell every console (``/console/reply``, level ``alert``, spoken) and the log."""
        log.error("%s", text)
        self.alerts.append(text)
        del self.alerts[:-100]
        msg = {
            "header": header(now=None),
            "text": text,
            "level": "alert",
            "speak": True,
            "utterance": "",
            "commands": "[]",
        }
        self.runtime.graph.publish("/console/reply", msg)

    async def _supervise(self, vp: VehicleProcess) -> None:
        delay = RESTART_BACKOFF_S[0]
        while not self._stopping:
            code = await vp.wait()
            if self._stopping:
                return
            vp.exits.append(code)
            if code == names.EXIT_CANNOT_START:  # it said why on its one line of stderr
                self.alert(f"{vp.name}'s flight process cannot start here; not restarting it.")
                return
            up_s = time.monotonic() - vp.started_at
            if up_s > STABLE_AFTER_S:
                delay = RESTART_BACKOFF_S[0]
            how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
            self.alert(
                f"{vp.name}'s flight process stopped ({how}); restarting it. "
                "The drone's own watchdog holds it meanwhile."
            )
            await asyncio.sleep(delay)
            delay = min(delay * 2, RESTART_BACKOFF_S[1])
            self._expect(vp.name)
            try:
                await vp.spawn()
            except OSError as exc:
                self.alert(f"{vp.name}'s flight process cannot be started: {exc}")
                continue
            log.warning("%s: vehicle process restarted (pid %s)", vp.name, vp.pid)


def flight_stacks_line(remote: list[str], local: list[str]) -> str:
    """``uav1, uav2 each in its own process`` (``--vehicles process``, MAVLink drones included)
    or ``uav1 in the web process (--vehicles inline)``."""
    parts = []
    if remote:
        each = "in its own process" if len(remote) == 1 else "each in its own process"
        parts.append(f"{', '.join(remote)} {each}")
    if local:
        parts.append(f"{', '.join(local)} in the web process (--vehicles inline)")
    return "; ".join(parts) or "no drone"


async def _terminate(vp: VehicleProcess, timeout_s: float = 10.0) -> None:
    """SIGTERM (the vehicle lands and stops), SIGKILL if it does not exit in time."""
    proc = vp.proc
    if proc is None and vp.adopted is not None:  # not our child: ask it to land and stop
        with contextlib.suppress(ProcessLookupError):
            os.kill(vp.adopted, signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        while _alive(vp.adopted) and time.monotonic() < deadline:
            await asyncio.sleep(0.1)
        return
    if proc is None or proc.returncode is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        proc.terminate()
    try:
        await asyncio.wait_for(proc.wait(), timeout_s)
    except TimeoutError:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        await proc.wait()


__all__ = ["VehicleCentral", "VehicleLinkSecurity", "child_env", "flight_stacks_line"]
