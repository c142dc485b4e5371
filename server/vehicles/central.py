"""The web process's side of vehicle processes: the bus, discovery, supervision.

- The bus: the console's own Zenoh router (:class:`~drone.bus.console.ConsoleBus`, docs/bus.md),
  which every vehicle joins as ``vehicle-NAME`` with its vehicle key
  (:mod:`server.vehicles.keys`; never the pilot or observer token) and where it may publish
  only under its own name. A vehicle runs no dialog: each drone's dialog runs here
  (:mod:`server.vehicles.console_dialog`); what a vehicle's nodes say comes under its own name
  and is re-published after a check (:mod:`server.vehicles.relay`), so this process is the
  only publisher of ``/console/reply``.
- Keys: ``serve`` makes one per vehicle it spawns (``<data dir>/vehicle-keys``) and hands it over
  in the child's environment (``UAVC_VEHICLE_KEY``), not on its command line. The bus follows
  the key directory while the console runs (:meth:`VehicleCentral._watch_keys`): a key made,
  replaced or revoked restarts the bus's router with the new access control, the vehicles on
  it rejoin by themselves, and the commands sent meanwhile wait for it (stops first).
- Discovery: every vehicle alive on the bus becomes a drone of the runtime
  (:class:`~server.vehicles.bus_remote.BusDroneStack` and its dialog), whether ``serve``
  spawned it or it joined from another host (``uav-console vehicle --bus-connect``).
- Heartbeat: this console's beat at 10 Hz, on the bus (its clock and the flight recording's
  id), so a vehicle can tell a stalled console, and on ``/vehicles/heartbeat``, so a page can.
- Supervision (``--vehicles process``, ``serve``'s default): one ``uav-console vehicle
  --bus-connect ENDPOINT`` child per drone, AR.Drone or MAVLink, each given its own ``--drone``
  entry (a simulator, AR.Drone or PX4, is started and owned by its vehicle), joining the
  console's bus router (:class:`~drone.bus.console.ConsoleBus`, which must start: see
  :meth:`VehicleCentral.open_bus`); when one exits (a crash, ``kill -9``) the console is told
  on ``/console/reply`` (level ``alert``) and the child is started again (backoff 0.5 s
  doubling to 5 s, reset after 30 s up). Children left by a ``serve`` that crashed are
  adopted: their pid files, and the pid in the ``vehicle/info`` they publish on the bus.
- Safety doors: each spawned vehicle gets its door's port (the same across restarts, so a
  page's Content-Security-Policy keeps naming it) and its door secret (``UAVC_DOOR_SECRET``),
  with which :meth:`VehicleCentral.door_ticket` mints the tickets pages open the door with.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import re
import signal
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drone.bus.commander import BusCommander
from drone.bus.config import BusTLS, endpoint_host, on_loopback, wants_tls
from drone.bus.console import ConsoleBus, Join
from drone.bus.errors import BusError
from drone.bus.session import DEFAULT_LISTEN
from server.http.tls import TLSError, ensure_ca, ensure_server_cert
from server.msgs import header
from server.settings import Settings, SettingsError
from server.vehicles import names
from server.vehicles.errors import NoBus
from server.vehicles.keys import KEY_ENV, WATCH_PERIOD_S, KeyWatch, VehicleKeys, vehicle_env
from server.vehicles.mavlink_stack import SIM_MAVLINK, drone_kind
from server.vehicles.relay import ReplyRelay
from server.vehicles.tickets import TICKET_TTL_S, DoorSecrets, mint

if TYPE_CHECKING:
    from server.runtime import Runtime
    from server.vehicles.console_dialog import RemoteDialog

log = logging.getLogger("uav_console")

RESTART_BACKOFF_S = (0.5, 5.0)
STABLE_AFTER_S = 30.0
DISCOVER_EVERY = 5  # heartbeat periods
# A router restart for new keys: the commands in flight get this long to be answered first,
# then the drones that were on the bus this long to be back (commands to them wait as long).
REKEY_DRAIN_S = 2.0
REKEY_REJOIN_S = 5.0


def pid_dir_of(settings: Settings) -> Path:
    """Where vehicle processes leave their pid (``NAME.pid``) while they run."""
    return names.pid_dir(settings.data_dir, settings.port)


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
    "clock_speed",
    "flight_time_s",
    "camera",
    "mavlink_sim_port",
    "mavlink_key",
    "allow_origins",
    "data_dir",
    "grammar_dir",
    "model_dir",
    "heartbeat_timeout_s",
    "command_deadline_s",
    "link_timeout_s",
    "confidence_threshold",
    "confirm_floor",
    "battery_low_pct",
    "battery_critical_pct",
    "altitude_ceiling_m",
    "ans_period_s",
    "search_after_s",
    "central_loss_land_s",
    "central_grace_s",
    "vehicle_nice",
    "control_rt_priority",
    "vehicle_rt_priority",
)


def child_env(settings: Settings, token: str) -> dict[str, str]:
    """The environment of a vehicle child: ours plus the settings it needs as ``UAVC_*``, and
    the pilot token as ``UAVC_TOKEN``, which only its safety port checks (it joins the bus with
    its own key: :func:`~server.vehicles.keys.vehicle_env`)."""
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
        self.keys = VehicleKeys(s.data_dir)
        # The prefix of each spawned vehicle's drone topics; any other vehicle's is /NAME.
        self.prefixes: dict[str, str] = {}
        self.processes: dict[str, VehicleProcess] = {}
        self.dialogs: list[RemoteDialog] = []
        self.relays: dict[str, ReplyRelay] = {}
        self.alerts: list[str] = []
        self._tasks: list[asyncio.Task[Any]] = []
        self._stopping = False
        self._recording_sent: str | None = None
        self._utterances: Any = None
        self.bus: ConsoleBus | None = None
        self.bus_error: str | None = None  # why the bus did not start (serve says it)
        self.commander: BusCommander | None = None
        self.door_secrets = DoorSecrets(pid_dir_of(s))
        self.door_ports: dict[str, int] = {}  # spawned vehicles' door ports

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        g = self.runtime.graph
        g.advertise(names.HEARTBEAT, names.STRING)
        g.advertise("/console/reply", "uav_console/Reply")
        # Subscribed before the drones' dialogs: the recording's id reaches the vehicles before
        # the command a dialog makes of the utterance.
        self._utterances = g.subscribe(
            "/console/utterance", lambda _msg: self.touch_recording(), type="uav_console/Utterance"
        )
        self._tasks.append(asyncio.create_task(self._beat(), name="vehicles-heartbeat"))
        self._tasks.append(asyncio.create_task(self._watch_keys(), name="vehicle-keys-watch"))

    async def _watch_keys(self) -> None:
        """Follow the vehicle key directory: once it has changed and kept still
        (:class:`~server.vehicles.keys.KeyWatch`), restart the bus's router with its keys
        (:meth:`rekey`). A file in it that holds no key is said in the log and changes
        nothing: the router keeps the keys it has until the directory is right."""
        watch = KeyWatch()
        while True:
            await asyncio.sleep(WATCH_PERIOD_S)
            if self.bus is None or not watch.observe(self.keys.signature(), time.monotonic()):
                continue
            scan = self.keys.scan()
            if scan.problems:
                for problem in scan.problems:
                    line = (
                        f"vehicle keys: {problem}; the bus keeps the vehicle keys it has until "
                        "that is fixed (`uav-console vehicle-key NAME --rotate` remakes one)"
                    )
                    log.error("%s", line)
                    print(f"uav-console: {line}", file=sys.stderr, flush=True)
                continue
            # a vehicle serve spawned keeps the key it was started with (its process has it)
            spawned = {n: vp.env[KEY_ENV] for n, vp in self.processes.items() if KEY_ENV in vp.env}
            try:
                await self.rekey({**scan.keys, **spawned})
            except BusError as exc:
                self.alert(f"the bus is down: its router did not restart: {exc}; retrying")
                watch.again(time.monotonic())
            except Exception:  # one failed look must not end the watch
                log.exception("vehicle keys: the bus was not rekeyed")
                watch.again(time.monotonic())

    async def rekey(self, passwords: Mapping[str, str]) -> bool:
        """Restart the bus's router for these vehicle keys (name → key) when they are not the
        ones it has; whether it restarted. Commands are held meanwhile
        (:meth:`~drone.bus.commander.BusCommander.hold`: those in flight answered first, new
        ones sent once the drones that were on the bus are back, stops first) and calls to
        those drones wait for them (:meth:`~server.vehicles.remote.RemoteDroneStack.expect`).

        Raises:
            BusError: the router did not open again (the bus is down).
        """
        from server.vehicles.remote import RemoteDroneStack

        bus, commander = self.bus, self.commander
        if bus is None or commander is None:
            return False
        if passwords == bus.vehicle_passwords and bus.router is not None:
            return False
        had = bus.vehicle_passwords
        # on the bus now and let in again: not a vehicle whose key is revoked or replaced
        before = {n for n in bus.alive() if n not in had or passwords.get(n) == had[n]}
        commander.hold()
        try:
            await commander.drained(REKEY_DRAIN_S)
            for name in before:
                stack = self.runtime.drones.get(name)
                if isinstance(stack, RemoteDroneStack):
                    stack.expect(REKEY_REJOIN_S)
            done = await asyncio.to_thread(bus.rekey, passwords)
            if done is None:
                return False
            back = before - set(done.changed)
            end = time.monotonic() + REKEY_REJOIN_S
            while not back <= set(bus.alive()) and time.monotonic() < end:
                await asyncio.sleep(0.02)
            missing = sorted(back - set(bus.alive()))
            if missing:
                log.error("bus: %s not back on the bus after its router restarted", missing)
            print(f"uav-console: {done.said()}", file=sys.stderr, flush=True)
            return True
        finally:
            commander.release()

    def flight_stacks(self) -> str:
        """Where each drone's flight stack runs, for ``serve``'s start-up lines."""
        from server.vehicles.remote import RemoteDroneStack

        drones = self.runtime.drones
        remote = [n for n, d in drones.items() if isinstance(d, RemoteDroneStack)]
        local = [n for n in drones if n not in remote]
        return flight_stacks_line(remote, local)

    def open_bus(self, count: int) -> None:
        """Open the console's bus router for drones ``uav1`` … ``uavN`` (``serve`` does it
        before it takes requests, so that a bus that cannot start stops it with one line).

        Raises:
            NoBus: the router could not start and there are vehicle processes to spawn, which
                reach the console only over it.
        """
        if self.bus is not None:
            return
        self.bus = self._open_bus([f"uav{index + 1}" for index in range(count)])
        if self.bus is None and count > 0:
            raise NoBus(
                f"the bus did not start: {self.bus_error}; the drones' flight processes join "
                "the console over it (--bus-listen ENDPOINT chooses where it listens; "
                "--vehicles inline runs the drones in this process)"
            )
        if self.bus is None:  # no drones of its own: the console runs on without a bus
            log.error("the bus did not start: %s", self.bus_error)
            self.alerts.append(f"the bus did not start: {self.bus_error}")

    async def spawn(self, count: int) -> None:
        """Register drones ``uav1`` … ``uavN`` now; start (or adopt) their vehicle processes in
        the background, once the server accepts connections (see :meth:`_orphans`). Each
        joins the console's bus (``uav-console vehicle --bus-connect ENDPOINT --name NAME``).

        Raises:
            NoBus: see :meth:`open_bus`.
        """
        s = self.runtime.settings
        tls = self.runtime.tls  # set by `serve` before the lifespan starts us
        # The safety port listens where the console does (a phone on the LAN reaches both),
        # over HTTPS with the console's certificate when the console speaks it.
        safety = ["--safety-host", s.host]
        if tls is not None:
            safety += ["--safety-cert", str(tls.cert), "--safety-key", str(tls.key)]
        env = child_env(s, self.runtime.tokens.pilot_token)
        self.open_bus(count)
        for index in range(count):
            name = f"uav{index + 1}"
            prefix = "" if count == 1 else f"/{name}"
            bus_argv, bus_env = self._bus_join(name)
            argv = [sys.executable, "-m", "server", "vehicle", *bus_argv, "--name", name]
            kind = drone_kind(s.drone, index)  # its own entry of a comma-separated --drone
            argv += ["--prefix", prefix, "--index", str(index), "--drone", kind]
            argv += ["--world", s.world, *safety, "--parent-pid", str(os.getpid())]
            self.door_ports[name] = free_door_port(s.host)
            argv += ["--safety-port", str(self.door_ports[name])]
            self.prefixes[name] = prefix
            child = {**vehicle_env(env, self.keys, name), **bus_env}
            child["UAVC_DOOR_SECRET"] = self.door_secrets.get_or_create(name).hex()
            self.processes[name] = VehicleProcess(argv, child, name)
            self._register(name, prefix, simulated=kind in ("sim", SIM_MAVLINK))
            self._expect(name)
        self._tasks.append(asyncio.create_task(self._launch(), name="vehicles-launch"))

    def _open_bus(self, vehicles: list[str]) -> ConsoleBus | None:
        """The console's embedded bus router (docs/bus.md); None, said in the log, when it
        cannot start."""
        s = self.runtime.settings
        try:
            tls = bus_tls(s)
        except TLSError as exc:
            self._bus_failed(str(exc))
            return None
        passwords = {v: self.keys.ensure(v).secret for v in vehicles}
        passwords |= {k.name: k.secret for k in self.keys.all()}  # vehicles from elsewhere
        bus = ConsoleBus(
            s.data_dir / "bus",
            s.fleet_name,
            vehicles,
            listen=s.bus_listen,
            connect=s.bus_connect,
            vehicle_passwords=passwords,
            name=console_name(s),
            tls=tls,
            shared_credentials=s.bus_credentials,
            on_join=self._said_join,
        )
        try:
            bus.start()
        except BusError as exc:
            self._bus_failed(str(exc))
            return None
        assert bus.session is not None
        self.commander = BusCommander(bus.session, s.fleet_name, console_name(s))
        return bus

    @staticmethod
    def _said_join(join: Join) -> None:
        """A router this console joins came, went, or is not up: on serve's output (the log
        has it too, on /rosout)."""
        print(f"uav-console: {join.said()}", file=sys.stderr, flush=True)

    def _bus_failed(self, why: str) -> None:
        """Why the bus did not start, in a line: without Zenoh's source locations."""
        why = why.removeprefix("the bus could not start: ")
        self.bus_error = re.sub(r" at /\S+\.rs:\d+\.?", "", why)

    def _bus_join(self, name: str) -> tuple[list[str], dict[str, str]]:
        """How vehicle ``name`` joins the bus: ``--bus-connect`` (our router first, then the
        routers we join: the vehicle fails over to them) and the rest of it in its environment
        (its password is its vehicle key, there already)."""
        assert self.bus is not None
        cred = self.bus.vehicle_credential(name)
        argv = ["--bus-connect", ",".join([*cred.connect, *self.runtime.settings.bus_connect])]
        env = {"UAVC_FLEET_NAME": self.runtime.settings.fleet_name}
        if cred.ca is not None:
            env["UAVC_BUS_CA"] = cred.ca
        return argv, env

    def door_ticket(self, name: str, now: float | None = None) -> str | None:
        """A pilot's ticket for ``name``'s safety door (None: a vehicle we gave no secret)."""
        secret = self.door_secrets.get(name)
        if secret is None:
            return None
        expires = (time.time() if now is None else now) + TICKET_TTL_S
        return mint(secret, name, "pilot", expires)

    def door_urls(self) -> list[str]:
        """Every safety door this console knows, as bound (scheme, host, port): those of the
        vehicles it spawned, whether they have joined yet or not, and those that announced
        one (a vehicle adopted, or joined from another host)."""
        from server.vehicles.remote import RemoteDroneStack

        s = self.runtime.settings
        scheme = "wss" if self.runtime.tls is not None else "ws"
        host = f"[{s.host}]" if ":" in s.host else s.host
        found = {f"{scheme}://{host}:{port}" for port in self.door_ports.values()}
        for stack in self.runtime.drones.values():
            if isinstance(stack, RemoteDroneStack) and stack.info.get("door_url"):
                found.add(str(stack.info["door_url"]))
        return sorted(found)

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
        directory name live processes): they rejoin our bus router, which listens where the
        crashed one did, within a second, and their ``vehicle/info`` (the pid) comes again
        within 2 s; wait ``wait_s`` for them, then adopt them. No pid file: no wait."""
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
        """The recording's id to the vehicles, at once in a beat on the bus (not only at the
        next one), when it changed."""
        if recording != self._recording_sent:
            self._recording_sent = recording
            if self.commander is not None:
                self.commander.beat(time.time(), recording)

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
        if self.commander is not None:
            self.commander.close()
            self.commander = None
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        for dialog in self.dialogs:
            dialog.close()
        self.dialogs.clear()
        for relay in self.relays.values():
            relay.close()
        self.relays.clear()

    def prefix_of(self, name: str) -> str:
        """The prefix of vehicle ``name``'s drone topics: what ``serve`` gave the vehicle it
        spawned, else ``/NAME`` (a vehicle does not choose it: it would pick another's)."""
        return self.prefixes.get(name, f"/{name}")

    # ------------------------------------------------------------------ drones
    def _register(self, name: str, prefix: str, *, simulated: bool) -> None:
        from server.dialog.adapters import CallableDescriber
        from server.vehicles.bus_remote import BusDroneStack
        from server.vehicles.console_dialog import RemoteDialog

        rt = self.runtime
        if name in rt.drones or self.commander is None or self.bus is None:
            return  # no bus: no vehicle reaches this console
        stack = BusDroneStack(
            rt.graph,
            name,
            prefix,
            self.commander,
            self.bus.alive,
            self.pilot,
            topics=bus_topics(name, prefix),
            simulated=simulated,
        )
        stack.touch_recording = self.touch_recording
        rt.drones[name] = stack
        # Its dialog runs here: it understands what is said to the drone and sends the
        # vehicle typed commands; it says the vehicle supervisor's alarms.
        dialog = RemoteDialog(
            rt.graph,
            rt.settings,
            stack,
            rt.world,
            CallableDescriber(lambda: rt.describe(name)),
            rt.audit,
            nlu=rt.nlu,
            fleet=rt.fleet.central,
            drones=lambda: list(rt.drones) or [name],
        )
        self.dialogs.append(dialog)
        rt.dialogs[name] = dialog
        self.relays[name] = ReplyRelay(rt.graph, name)  # what its own nodes say
        self._tasks.append(asyncio.create_task(dialog.run(), name=f"dialog:{name}"))
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

    def pilot(self) -> str:
        """Who commands at this console now, for the vehicles' lease: the holder of this
        console's pilot lease (a page's session, ``rest``), else any pilot of it."""
        holder = self.runtime.security.lease.state.holder
        return holder[:128] if holder else "pilot"

    def discover(self) -> None:
        """Register every vehicle alive on the bus that is not a drone yet."""
        if self.bus is None or self.commander is None:
            return
        for name in self.bus.alive():
            if name not in self.runtime.drones:
                status = self.commander.status(name)
                simulated = status.simulated if status is not None else True
                self._register(name, self.prefix_of(name), simulated=simulated)

    async def _beat(self) -> None:
        n = 0
        while True:
            # Our clock in each beat: a vehicle learns its offset from it (command deadlines).
            now = time.time()
            # the pages' and rosbridge clients' beat: they call the server road down without it
            beat = json.dumps({"n": n, "t": now})
            self.runtime.graph.publish(names.HEARTBEAT, {"data": beat})
            if self.commander is not None:
                self.commander.beat(now, self.runtime.recording_id() or "")
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


def bus_topics(name: str, prefix: str) -> dict[str, Any]:
    """The graph topics vehicle ``name`` may show on this console over the bus: its drone's
    (AR.Drone, with GPS navdata, or MAVLink) under its prefix, and its own ``/NAME/vehicle/*``
    (the camera comes on its own key)."""
    from server.vehicles.host import shared_topics

    out: dict[str, Any] = {}
    for mavlink in (False, True):
        for topic in shared_topics(name, prefix, mavlink=mavlink, gps=True):
            if not topic.name.endswith("/image_raw/compressed"):
                out[topic.name] = topic
    return out


def bus_tls(settings: Settings) -> BusTLS | None:
    """The bus router's TLS (docs/bus.md#tls): a ``bus.pem`` signed by the console's local CA
    (the one HTTPS uses), naming the host it listens on and this machine's names and
    addresses; when ``bus_tls`` leaves it off, the CA alone where it joins a ``tls/`` router,
    else None.

    Raises:
        TLSError: the CA or the certificate cannot be made or read.
    """
    listen = list(settings.bus_listen) or [DEFAULT_LISTEN]
    if not wants_tls(settings.bus_tls, listen):
        if any(e.startswith("tls/") for e in settings.bus_connect):  # joins a TLS router
            if settings.bus_ca is not None:  # another console's CA (--bus-ca)
                return BusTLS(str(settings.bus_ca.resolve()))
            return BusTLS(str(ensure_ca(settings.data_dir.resolve() / "tls")[0]))
        return None
    hosts = [endpoint_host(e) for e in listen if not on_loopback(e)] or ["127.0.0.1"]
    files = ensure_server_cert(settings.data_dir.resolve() / "tls", hosts[0], stem="bus")
    assert files.ca is not None  # the local CA's certificate, always made with it
    return BusTLS(str(files.ca), str(files.cert), str(files.key))


def console_name(settings: Settings) -> str:
    """This console's name on the bus (``console_name``, else ``HOST-PORT``)."""
    from server.fleet.failover import default_console_name

    return settings.console_name or default_console_name(settings.host, settings.port)


def free_door_port(host: str) -> int:
    """A TCP port free on ``host`` now, for a vehicle's safety door (kept across restarts)."""
    import socket

    bind = "0.0.0.0" if host in ("", "0.0.0.0") else host
    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    with socket.socket(family) as sock:
        sock.bind((bind, 0))
        return int(sock.getsockname()[1])


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


__all__ = ["VehicleCentral", "child_env", "flight_stacks_line"]
