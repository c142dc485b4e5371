"""Replay in the page: a recorded flight played by the running console, read-only.

The page opens ``/?replay=FLIGHT_ID`` (the Recordings menu) and talks to this flight's replay
exactly as it talks to the live console, under another base:

- ``/api/v1/replays/{id}/rosbridge``: a rosbridge door onto the replay's **own graph**, on
  which a :class:`~server.recorder.replay.Player` publishes the recording. Nothing that flies
  is on that graph: no drone, no dialog, no vehicle link. Every token is an observer's there
  (:class:`ReplaySecurity`), with a pilot lease of its own, so a replay can neither command a
  drone nor take the live lease.
- ``GET /api/v1/replays/{id}/world``, ``/drones``, ``/drones/{name}``: the recorded world and
  drones (what they reported, ``replay: true``); ``POST /drones/{name}/{action}`` answers 409.
- ``GET|POST /api/v1/replays/{id}/replay``: the timeline (play, pause, seek, speed), as
  ``uav-console replay`` serves it.

A replay is opened on first use and shared by the pages that watch the same flight; at most
``MAX_OPEN`` are open (each holds its decoded flight in memory), and one nobody has used for
``IDLE_CLOSE_S`` is closed. The flight being recorded cannot be replayed until it ends (409).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fastapi import APIRouter, HTTPException, Request, WebSocket

from drone.sim.world import WorldError, load_world
from server.api.deps import RoleDep
from server.api.models import ActionResult, DroneInfo, WorldInfo
from server.graph import Graph
from server.http.security import PilotLease, Role, Security, token_from
from server.recorder.errors import CorruptRecording, FlightNotFound
from server.recorder.index import FlightIndex, drones_of, iso
from server.recorder.mcapfile import Recording
from server.recorder.replay import Played, Player, Timeline, flight_start_ns, load
from server.recorder.replay_drone import ReplayCommand, ReplayDrone, ReplayStatus
from server.rosbridge.context import BridgeContext
from server.rosbridge.endpoint import serve_rosbridge, setup_graph

log = logging.getLogger("uav_console.replay")

MAX_OPEN = 2
IDLE_CLOSE_S = 300.0
CLOSE_POLICY = 1008  # RFC 6455 §7.4.1: policy violation (unknown flight, refused)


class ReplaySecurity(Security):
    """The live console's tokens, every one an observer's; a pilot lease of its own."""

    def __init__(self, live: Security) -> None:
        super().__init__(live.settings, live.tokens)
        self.lease = PilotLease()  # never the live one: a replay page cannot take it

    def role_for(self, token: str | None) -> Role | None:
        return Role.OBSERVER if super().role_for(token) is not None else None


@dataclass
class ReplaySession:
    """One flight being replayed: its graph, player, drones, world and rosbridge context."""

    flight_id: str
    file: str
    recording: Recording
    graph: Graph
    player: Player
    bridge: BridgeContext
    drones: dict[str, ReplayDrone]
    world: dict[str, Any]
    used: float
    connections: int = 0
    task: asyncio.Task[None] | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def status(self) -> dict[str, Any]:
        """The timeline as ``GET /replay`` of ``uav-console replay`` says it."""
        tl = self.player.timeline
        tl.update(self.player.now())
        return {**self.info, **tl.status(), "started": iso(tl.start_ns), "ended": iso(tl.end_ns)}

    async def close(self) -> None:
        if self.task is not None:
            self.task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self.task
            self.task = None


class ReplayHub:
    """The replays the running console has open (see the module docstring)."""

    def __init__(
        self,
        index: Callable[[], FlightIndex],
        recording_id: Callable[[], str | None],
        security: Security,
        live_world: Callable[[], dict[str, Any]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._index = index
        self._recording_id = recording_id
        self._security = ReplaySecurity(security)
        self._live_world = live_world
        self._clock = clock
        self._open: dict[str, ReplaySession] = {}
        self._lock = asyncio.Lock()

    @property
    def open_ids(self) -> list[str]:
        return list(self._open)

    def now(self) -> float:
        return self._clock()

    def admits(self, token: str | None) -> bool:
        """Whether ``token`` is one of the console's (a replay is opened for no one else)."""
        return self._security.role_for(token) is not None

    async def get(self, flight_id: str) -> ReplaySession:
        """The replay of ``flight_id``, opened (and started playing) on first use.

        Raises:
            HTTPException: 404 unknown flight, 409 still being recorded, 422 unreadable,
                503 too many replays watched at once.
        """
        async with self._lock:
            now = self._clock()
            session = self._open.get(flight_id)
            if session is None:
                await self._close_idle(now)
                if len(self._open) >= MAX_OPEN:
                    raise HTTPException(
                        status_code=503,
                        detail=f"{MAX_OPEN} replays are being watched; close one first",
                    )
                session = await self._load(flight_id, now)
                self._open[flight_id] = session
            session.used = now
            return session

    async def _close_idle(self, now: float) -> None:
        for fid, s in list(self._open.items()):
            if s.connections == 0 and (now - s.used > IDLE_CLOSE_S or len(self._open) >= MAX_OPEN):
                await s.close()
                del self._open[fid]
                log.info("replay of %s closed (nobody watching)", fid)

    async def _load(self, flight_id: str, now: float) -> ReplaySession:
        if flight_id == self._recording_id():
            raise HTTPException(
                status_code=409,
                detail=f"flight '{flight_id}' is being recorded; replay it once it has ended",
            )
        try:
            path = self._index().path_for(flight_id)
        except FlightNotFound as exc:
            raise HTTPException(status_code=404, detail=str(exc)) from exc
        try:
            # Reading and decoding a flight is seconds of CPU: not on the event loop.
            recording, played = await asyncio.to_thread(load, path, recover=True)
        except (CorruptRecording, OSError) as exc:
            raise HTTPException(status_code=422, detail=f"cannot replay: {exc}") from exc
        if not played:
            raise HTTPException(status_code=422, detail=f"flight '{flight_id}' holds no messages")
        session = self._session(flight_id, str(path), recording, played, now)
        session.task = asyncio.create_task(session.player.run(), name=f"replay-{flight_id}")
        session.player.play()
        log.info("replaying %s (%d messages)", flight_id, len(played))
        return session

    def _session(
        self, flight_id: str, file: str, recording: Recording, played: list[Played], now: float
    ) -> ReplaySession:
        graph = Graph()
        graph.bind_loop(asyncio.get_running_loop())
        timeline = Timeline(played, start_ns=flight_start_ns(recording))
        player = Player(graph, timeline)
        player.advertise()
        names = drones_of(list(recording.topics)) or ["uav1"]
        # A drone's topics are prefixed /NAME in a fleet and bare for a single drone.
        prefixes = {
            n: f"/{n}" if any(t.startswith(f"/{n}/") for t in recording.topics) else ""
            for n in names
        }
        drones = {n: ReplayDrone.make(n, prefixes[n], player) for n in names}
        bridge = BridgeContext(graph, self._security, self._security.settings)
        setup_graph(bridge)
        world_name = recording.metadata.get("flight", {}).get("world") or ""
        try:
            world = load_world(world_name).to_dict() if world_name else self._live_world()
        except (WorldError, OSError) as exc:
            log.warning("replay of %s: world %r not loaded (%s)", flight_id, world_name, exc)
            world = self._live_world()
        info = {
            "id": flight_id,
            "file": file,
            "drones": names,
            "complete": recording.complete,
        }
        return ReplaySession(
            flight_id, file, recording, graph, player, bridge, drones, world, now, info=info
        )

    async def close(self) -> None:
        """Close every replay (the console stops)."""
        async with self._lock:
            for s in self._open.values():
                await s.close()
            self._open.clear()


def _hub(request: Request | WebSocket) -> ReplayHub:
    hub = getattr(request.app.state, "replays", None)
    if hub is None:
        raise HTTPException(status_code=404, detail="this console replays no flights")
    return hub  # type: ignore[no-any-return]


router = APIRouter(prefix="/replays/{flight_id}", tags=["replay"])


@router.get("", response_model=ReplayStatus)
@router.get("/replay", response_model=ReplayStatus)
async def replay_status(flight_id: str, request: Request, _role: RoleDep) -> dict[str, Any]:
    """The replay's timeline: position, duration, playing, speed, drones (opens it)."""
    return (await _hub(request).get(flight_id)).status()


@router.post("/replay", response_model=ReplayStatus)
async def replay_control(
    flight_id: str, body: ReplayCommand, request: Request, _role: RoleDep
) -> dict[str, Any]:
    """Play, pause, seek (``position_s`` from the start) or set the ``speed``."""
    session = await _hub(request).get(flight_id)
    player = session.player
    if body.action == "play":
        player.play()
    elif body.action == "pause":
        player.pause()
    elif body.action == "seek":
        if body.position_s is None:
            raise HTTPException(status_code=422, detail="seek needs position_s")
        player.seek(body.position_s)
    else:
        if body.speed is None:
            raise HTTPException(status_code=422, detail="speed needs speed")
        player.set_speed(body.speed)
    return session.status()


@router.get("/world", response_model=WorldInfo, response_model_exclude_unset=True)
async def replay_world(flight_id: str, request: Request, _role: RoleDep) -> dict[str, Any]:
    """The world the flight was flown in."""
    return (await _hub(request).get(flight_id)).world


@router.get("/drones", response_model=list[DroneInfo], response_model_exclude_unset=True)
async def replay_drones(flight_id: str, request: Request, _role: RoleDep) -> list[dict[str, Any]]:
    """Every recorded drone as it reported at this point of the replay."""
    session = await _hub(request).get(flight_id)
    return [d.telemetry() for d in session.drones.values()]


@router.get("/drones/{name}", response_model=DroneInfo, response_model_exclude_unset=True)
async def replay_drone(
    flight_id: str, name: str, request: Request, _role: RoleDep
) -> dict[str, Any]:
    """One recorded drone at this point of the replay."""
    session = await _hub(request).get(flight_id)
    drone = session.drones.get(name)
    if drone is None:
        raise HTTPException(status_code=404, detail=f"no drone '{name}' in this flight")
    return drone.telemetry()


@router.post(
    "/drones/{name}/{action}",
    response_model=ActionResult,
    responses={409: {"description": "always: a replay commands nothing"}},
)
async def replay_refuses(flight_id: str, name: str, action: str, _role: RoleDep) -> None:
    """A replay commands nothing."""
    raise HTTPException(
        status_code=409, detail=f"this is a replay of flight {flight_id}: it cannot {action}"
    )


@router.websocket("/rosbridge")
async def replay_rosbridge(websocket: WebSocket, flight_id: str) -> None:
    """The rosbridge door onto the replay's graph (read-only: every client an observer).

    The token is checked before the flight is opened (opening one costs seconds of CPU); the
    page's ``?token=`` or cookie, as on the live door."""
    try:
        hub = _hub(websocket)
        if not hub.admits(token_from(websocket.headers, websocket.query_params, websocket.cookies)):
            raise HTTPException(status_code=401, detail="invalid token")
        session = await hub.get(flight_id)
    except HTTPException as exc:
        await websocket.close(code=CLOSE_POLICY, reason=str(exc.detail)[:120])
        return
    session.connections += 1
    try:
        await serve_rosbridge(websocket, session.bridge)
    finally:
        session.connections -= 1
        session.used = hub.now()
