"""The composition root: everything one server process runs, started and stopped together.

``Runtime`` owns the graph, security, the world, one :class:`DroneStack` per drone (simulator if
any, driver, vehicle, task manager, graph node, dialog manager), the captioner and the fleet's
central task manager. The FastAPI app and the CLI only talk to it.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

from fastapi import APIRouter

from drone.sim.world import World, load_world
from drone.vehicle import Vehicle
from server.captioner import (
    Captioner,
    CaptionerUnavailable,
    describe_timed,
)
from server.captioner.service import load_captioner, unavailable_text
from server.dialog.adapters import CallableDescriber, TaskManagerPort, VehicleAdapter
from server.dialog.addressing import parse_address
from server.dialog.manager import UTTERANCE, DialogManager
from server.fleet.planner import FlightModel
from server.fleet.service import FleetService
from server.graph import Graph
from server.http.audit_trail import AuditTrail
from server.http.security import Security, TokenStore
from server.http.tls import TLSFiles, display_host
from server.language.nlu import default_nlu
from server.nodes.rosout import Rosout
from server.recorder.index import FlightIndex, FlightInfo
from server.recorder.recorder import Recorder, config_from_settings
from server.rosbridge.context import BridgeContext
from server.rosbridge.endpoint import make_router, serve_rosbridge_port
from server.settings import Settings
from server.speech.gaps import FILE_NAME as GAP_FILE
from server.speech.service import SpeechConfig, SpeechService
from server.store import AuditLog
from server.tasks.manager import TaskManager
from server.vehicles import names
from server.vehicles.central import VehicleCentral
from server.vehicles.mavlink_stack import drone_kind
from server.vehicles.stack import DroneStack, build_drone_stack

UTTERANCE_TYPE = "uav_console/Utterance"
log = logging.getLogger("uav_console")


@dataclass
class Runtime:
    """Everything one server process runs; ``await start()`` then ``await stop()``."""

    settings: Settings
    graph: Graph = field(default_factory=Graph)
    drones: dict[str, DroneStack] = field(default_factory=dict)
    dialogs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        s = self.settings
        self.tokens = TokenStore(s.data_dir, pilot_token=s.token, observer_token=s.observer_token)
        self.security = Security(s, self.tokens)
        self.world: World = load_world(s.world)
        self.bridge = BridgeContext(self.graph, self.security, s)
        self.nlu = default_nlu(str(s.grammar_dir))
        self.audit = AuditLog(s.data_dir / "audit.db")
        self.trail = AuditTrail(self.audit)  # intent/outcome rows of direct actions
        self.bridge.audit = self.trail
        self.security.lease.on_change = self.trail.lease_changed
        self.security.actions_of = self.actions_of  # lease judged by what an utterance asks
        self._routers: list[APIRouter] = [make_router(self.bridge)]
        self.fleet = FleetService(
            self.graph, self.world, model=FlightModel.for_flight_time(s.flight_time_s)
        )
        self._tasks: list[asyncio.Task[Any]] = []
        self._captioner: Captioner | CaptionerUnavailable = load_captioner(s.model_dir)
        self.started_at = time.time()
        self.tls: TLSFiles | None = None  # set by `serve` when it serves HTTPS
        self.speech = SpeechService(
            SpeechConfig(
                s.asr_model,
                s.asr_model_sha256,
                s.asr_workers,
                queue=s.asr_queue,
                window_s=s.asr_window_s,
                beams=s.asr_beams,
                threshold=s.confidence_threshold,
                gap_log=s.data_dir / GAP_FILE,
            ),
            self.nlu,
        )
        # vehicle processes (``--vehicles process``) and vehicles from elsewhere: the bus, discovery
        self.vehicles = VehicleCentral(self)
        # Flight recorder (server/recorder): every graph topic to MCAP, one file per session.
        recorder_config = config_from_settings(s)
        self.flight_index = FlightIndex(recorder_config.directory, recorder_config.budget_bytes)
        self.recorder: Recorder | None = None
        if s.recorder:
            self.recorder = Recorder(self.graph, recorder_config, drones=lambda: self.drones)
            self.flight_index = self.recorder.index
        self.rosout = Rosout(self.graph)

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        self.graph.bind_loop(asyncio.get_running_loop())
        self.rosout.attach()
        if self.recorder is not None:
            await asyncio.to_thread(self.recorder.start)  # repairs what a crash left first
            self.audit.recording = self.recorder.touch
        self.graph.advertise_service(
            "/console/describe", "uav_console/Describe", self._describe_service
        )
        if isinstance(self._captioner, CaptionerUnavailable):
            log.warning(self.captioner_status())
        from server import timewarp

        if self.settings.clock_speed != timewarp.speed():
            log.warning(
                "clock_speed %g is only honoured from the command line or UAVC_CLOCK_SPEED "
                "(python -m server installs it first); this process runs at %g×",
                self.settings.clock_speed,
                timewarp.speed(),
            )
        elif timewarp.speed() != 1.0:
            log.warning("the console's clock runs at %g× the wall clock", timewarp.speed())
        if self.settings.drone.startswith("sim") and self.settings.sim_speed != 1.0:
            log.warning(
                "simulator at %.1f× real time: the EKF and the 100 Hz PID run on the wall clock, "
                "so the simulated drone reacts %.1f× faster than they expect; autonomous flight "
                "is only faithful at speed 1",
                self.settings.sim_speed,
                self.settings.sim_speed,
            )
        count = 0 if self.settings.drone == "none" else self.settings.fleet
        await self.vehicles.start()
        process = self.settings.vehicles == "process"
        if process:
            await self.vehicles.spawn(count)
            count = 0
        for index in range(count):
            name = f"uav{index + 1}"
            prefix = "" if count == 1 else f"/{name}"
            self.drones[name] = await self._start_drone(name, prefix, index)
        for stack in self.drones.values():
            if stack.tasks is not None:
                self.fleet.add_local(stack.name, stack.vehicle, stack.tasks)
        await self.fleet.start()
        bus = self.vehicles.bus
        if bus is not None and bus.session is not None:  # the central role, elected on the bus
            from server.vehicles.central import console_name

            name = console_name(self.settings)
            await self.fleet.join_bus(bus.session, self.settings.fleet_name, name)
        await self.speech.start(preload=self.settings.asr_preload)
        if self.settings.rosbridge_port:
            port = self.settings.rosbridge_port
            serving = serve_rosbridge_port(self.settings.host, port, self.bridge)
            self._tasks.append(asyncio.create_task(serving, name="rosbridge-port"))

    async def _start_drone(self, name: str, prefix: str, index: int) -> DroneStack:
        s = self.settings
        kind = drone_kind(s.drone, index)
        stack = await build_drone_stack(
            name, prefix, index, kind, self.world, s, self.graph, self.audit
        )
        assert stack.node is not None and stack.tasks is not None
        await stack.node.start()
        dialog = self._start_dialog(name, prefix, stack.vehicle, stack.tasks)
        if stack.supervisor is not None:  # its alarms: spoken by the dialog, and published
            stack.supervisor.on_alarm(dialog.hear)
            topic = names.alarm_topic(name)
            self.graph.advertise(topic, names.STRING)
            stack.supervisor.on_alarm(
                lambda alarm: self.graph.publish(
                    topic, {"data": json.dumps(alarm.as_message(name))}
                )
            )
            run = stack.supervisor.run(stack.vehicle.clock.now)
            self._tasks.append(asyncio.create_task(run, name=f"supervisor:{name}"))
        return stack

    def _start_dialog(
        self, name: str, prefix: str, vehicle: Vehicle, tasks: TaskManager
    ) -> DialogManager:
        """The drone's dialog manager, following the drone until ``stop``."""
        dialog = DialogManager(
            self.graph,
            self.settings,
            TaskManagerPort(tasks),
            VehicleAdapter(vehicle, self.world),
            CallableDescriber(lambda: self.describe(name)),
            self.audit,
            vehicle.clock.now,
            nlu=self.nlu,
            drone=name,
            prefix=prefix,
            fleet=self.fleet.central,
            drones=lambda: list(self.drones) or [name],
        )
        self.dialogs[name] = dialog
        self._tasks.append(asyncio.create_task(dialog.run(), name=f"dialog:{name}"))
        return dialog

    async def stop(self) -> None:
        await self.fleet.leave_bus()  # its tokens go before the bus does
        await self.vehicles.stop()
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        await self.fleet.stop()
        for stack in self.drones.values():
            if stack.node is not None:
                await stack.node.stop()
                stack.node.close()
            with contextlib.suppress(Exception):
                await stack.vehicle.stop(land=True)
            with contextlib.suppress(Exception):
                await stack.driver.stop()
            if stack.sim is not None:
                await stack.sim.stop()
        await self.speech.stop()
        if self.recorder is not None:
            self.audit.recording = None
            await asyncio.to_thread(self.recorder.stop)
        self.rosout.detach()
        self.bridge.close()
        self.audit.close()
        if isinstance(self._captioner, Captioner):
            self._captioner.close()

    # ------------------------------------------------------------------ queries
    @property
    def default_drone(self) -> str:
        return next(iter(self.drones), "uav1")

    def extra_routers(self) -> list[APIRouter]:
        return list(self._routers)

    def flights(self) -> list[FlightInfo]:
        """The flight recordings, oldest first (the one being recorded with ``ended`` None)."""
        if self.recorder is not None:
            return self.recorder.flights()
        return self.flight_index.listing()

    def recording_id(self) -> str | None:
        """The id of the flight being recorded now, if any."""
        return self.recorder.current_id if self.recorder is not None else None

    def captioner_status(self) -> str:
        """'ready', or why scene description is unavailable (said at start-up and in /health)."""
        if isinstance(self._captioner, CaptionerUnavailable):
            return unavailable_text(self._captioner.reason)
        return "ready"

    def note_utterance(self, text: str, *, source: str, confidence: float, drone: str) -> None:
        """Publish an operator's sentence that came through a door answering it by itself
        (REST ``POST /command``, ``POST /speech``) on ``/console/utterance``, marked
        ``answered`` so no dialog acts on it again: every input, whatever its door, is on the
        graph and in the flight recording, just before its reply (DESIGN §4)."""
        msg = {
            "text": text,
            "confidence": confidence if math.isfinite(confidence) else 0.0,
            "source": source,
            "drone": drone,
            "asked_by": "",
            "answered": True,
        }
        self.graph.publish(UTTERANCE, msg, type=UTTERANCE_TYPE)

    def interpret(self, text: str, state: str | None) -> list[dict[str, Any]]:
        """NLU only (raises ``UnknownStateError``, a ``KeyError``, for an unknown state)."""
        return self.nlu.interpret(text, state or None)

    def actions_of(self, text: str) -> set[str]:
        """The actions an operator's sentence asks ("uav2 land" → {"land"}), as ``POST
        /command`` judges it against the lease."""
        return {str(c["action"]) for c in self.interpret(parse_address(text).text, None)}

    async def describe(self, drone: str) -> tuple[str, float | None]:
        """Describe ``drone``'s latest camera frame in words the image supports: (sentence, ms),
        or (why not, None); marker ids from the frame and the vehicle's perception.

        Raises:
            LookupError: no such drone.
        """
        stack = self.drones.get(drone)
        if stack is None:
            raise LookupError(f"no drone '{drone}'")
        frame = stack.driver.latest_frame
        seen = stack.seen_markers() if frame is not None else []
        return await describe_timed(self._captioner, frame, markers=seen)

    async def _describe_service(self, args: dict[str, Any]) -> dict[str, Any]:
        name = str(args.get("drone") or self.default_drone)
        text, ms = await self.describe(name)
        return {"drone": name, "text": text, "ms": ms if ms is not None else -1.0}

    def announcement(self) -> list[str]:
        """The pilot's clickable URL (Jupyter style), then the observer's, indented."""
        scheme = "https" if self.tls is not None else "http"
        base = f"{scheme}://{display_host(self.settings.host)}:{self.settings.port}/"
        lines = [
            f"{base}?token={self.tokens.pilot_token}",
            f"  observer (watch only): {base}?token={self.tokens.observer_token}",
        ]
        lines.append(f"  flight stacks: {self.vehicles.flight_stacks()}")
        bus = self.vehicles.bus
        if bus is not None:
            endpoints = ", ".join(bus.listen)
            lines.append(f"  bus: {endpoints} · Zenoh client configuration: {bus.client_file}")
        elif self.vehicles.bus_error is not None:
            lines.append(f"  bus: did not start: {self.vehicles.bus_error}")
        if self.tls is not None:
            lines.append(f"  certificate SHA-256: {self.tls.fingerprint}")
            if self.tls.ca is not None:
                lines.append(f"  trust once on a phone: {base}api/v1/tls/ca.pem ({self.tls.ca})")
        return lines
