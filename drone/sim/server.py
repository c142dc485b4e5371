"""``SimServer``: the simulator behind the real AR.Drone 2.0 sockets on its own loopback address.

It binds UDP 5554 (navdata), UDP 5556 (AT) and TCP 5555 (video) on e.g. 127.0.0.2, exactly as a
drone does on 192.168.1.1: navdata goes from port 5554 to the address and port the client's init
datagram came from (pyardrone checks the source), AT datagrams feed ``SimDrone.receive_at``, and
TCP clients get PaVE-framed H.264 at 15 fps (``drone.ardrone.video``) rendered by
``drone.sim.camera``. Physics runs in real time times ``speed`` in sub-steps of at most 10 ms of
simulated time. ``run_sim`` is what ``uav-console sim`` calls.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drone.sim.drone import SimConfig, SimDrone, Truth
from drone.sim.errors import AddressInUse, SimConfigError

log = logging.getLogger(__name__)

MAX_SUBSTEP_S = 0.01  # physics step (sim seconds)
TICK_S = 0.005  # real seconds between loop turns


@dataclass(frozen=True)
class SimPorts:
    """The drone's ports (Developer Guide §3: 5554 navdata, 5555 video, 5556 AT)."""

    navdata: int = 5554
    video: int = 5555
    at: int = 5556

    @classmethod
    def shifted(cls, index: int) -> SimPorts:
        """Ports for the ``index``-th simulator sharing 127.0.0.1 (macOS fallback)."""
        base = 15554 + 10 * index
        return cls(navdata=base, video=base + 1, at=base + 2)


def loopback_usable(addr: str) -> bool:
    """Whether ``addr`` can be bound here (Linux: all of 127/8; macOS: only 127.0.0.1)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((addr, 0))
        except OSError:
            return False
    return True


def in_use(addr: str, sockets: list[tuple[str, int]]) -> str | None:
    """Which of ``sockets`` (("udp" | "tcp", port)) cannot be bound on ``addr`` now because it
    is in use ("UDP 5554 on 127.0.0.2"), or None when every one can (each is closed again at
    once). A TCP port is probed with SO_REUSEADDR, as asyncio's servers bind: only a listening
    socket counts, not the TIME_WAIT of old connections.

    Raises:
        OSError: ``addr`` cannot be bound for another reason (not a local address).
    """
    for proto, port in sockets:
        kind = socket.SOCK_DGRAM if proto == "udp" else socket.SOCK_STREAM
        with socket.socket(socket.AF_INET, kind) as s:
            if kind == socket.SOCK_STREAM:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((addr, port))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    return f"{proto.upper()} {port} on {addr}"
                raise
    return None


def sim_sockets(ports: SimPorts) -> list[tuple[str, int]]:
    """The sockets an AR.Drone simulator binds (navdata, AT, video)."""
    return [("udp", ports.navdata), ("udp", ports.at), ("tcp", ports.video)]


def sim_endpoint(index: int, base_addr: str = "127.0.0.2") -> tuple[str, SimPorts]:
    """Address and ports of the ``index``-th simulated drone (0-based): 127.0.0.(2+index) with the
    standard ports, or 127.0.0.1 with shifted ports where other loopback addresses are unusable."""
    parts = base_addr.split(".")
    addr = ".".join([*parts[:3], str(int(parts[3]) + index)])
    if loopback_usable(addr):
        return addr, SimPorts()
    return "127.0.0.1", SimPorts.shifted(index)


class _NavdataPort(asyncio.DatagramProtocol):
    def __init__(self, server: SimServer) -> None:
        self.server = server
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.server._navdata_request(data, addr)


class _ATPort(asyncio.DatagramProtocol):
    def __init__(self, server: SimServer) -> None:
        self.server = server

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.server._at(data)


class SimServer:
    """A simulated AR.Drone 2.0 on ``addr``; ``await start()`` binds, ``await stop()`` closes.

    Args:
        addr: loopback address to bind (the "drone IP").
        world: a ``World``, a world name/path for ``drone.sim.world.load_world``, or None (a bare
            8 × 6 × 3 m room, no camera).
        ports: the three ports (default 5554/5555/5556).
        speed: real-time factor (2.0 = simulated time runs twice as fast as the wall clock).
        sim: an existing ``SimDrone`` to serve (then ``world`` and ``seed`` are ignored).
        seed: simulator seed.
        video_fps: camera frame rate in simulated time.
        clock: monotonic wall clock (injectable).

    Raises:
        SimConfigError: speed not positive and finite.
    """

    def __init__(
        self,
        addr: str = "127.0.0.2",
        world: Any | None = None,
        *,
        ports: SimPorts | None = None,
        speed: float = 1.0,
        sim: SimDrone | None = None,
        seed: int = 1,
        config: SimConfig | None = None,
        video_fps: float = 15.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (math.isfinite(speed) and speed > 0):
            raise SimConfigError(f"speed must be a positive number, got {speed!r}")
        if isinstance(world, str):
            from drone.sim.world import load_world

            world = load_world(world)
        self.addr = addr
        self.ports = ports or SimPorts()
        self.speed = speed
        self.sim = sim if sim is not None else SimDrone(world, seed=seed, config=config)
        self.video_fps = video_fps
        self.clock = clock
        self.client: tuple[str, int] | None = None  # where navdata goes
        self.navdata_sent = 0
        self.video_frames_sent = 0
        self.video_clients: set[asyncio.StreamWriter] = set()
        self._nav: _NavdataPort | None = None
        self._transports: list[asyncio.BaseTransport] = []
        self._tcp: asyncio.Server | None = None
        self._task: asyncio.Task[None] | None = None
        self._video_task: asyncio.Task[None] | None = None
        self._video_wake = asyncio.Event()

    # ---------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        """Bind the three sockets and start the physics loop.

        Raises:
            AddressInUse: one of its sockets is already bound (another simulator there).
            OSError: an address/port is unavailable otherwise (not a local address).
        """
        loop = asyncio.get_running_loop()
        taken = in_use(self.addr, sim_sockets(self.ports))
        if taken is not None:
            raise AddressInUse(f"the simulator's {taken} is in use")
        try:
            nav_t, nav_p = await loop.create_datagram_endpoint(
                lambda: _NavdataPort(self), local_addr=(self.addr, self.ports.navdata)
            )
        except OSError as exc:  # taken between the look and the bind
            if exc.errno != errno.EADDRINUSE:
                raise
            what = f"UDP {self.ports.navdata} on {self.addr}"
            raise AddressInUse(f"the simulator's {what} is in use") from None
        self._transports.append(nav_t)
        self._nav = nav_p
        try:
            at_t, _ = await loop.create_datagram_endpoint(
                lambda: _ATPort(self), local_addr=(self.addr, self.ports.at)
            )
            self._transports.append(at_t)
            self._tcp = await asyncio.start_server(self._video_client, self.addr, self.ports.video)
        except OSError:
            await self.stop()
            raise
        self._task = asyncio.create_task(self._run(), name=f"sim@{self.addr}")
        if self.sim.world is not None:
            self._video_task = asyncio.create_task(self._video(), name=f"sim-video@{self.addr}")

    async def stop(self) -> None:
        """Stop the loops and close every socket (idempotent)."""
        tasks = [t for t in (self._task, self._video_task) if t is not None]
        for task in tasks:
            task.cancel()
        if tasks:
            done, pending = await asyncio.wait(tasks, timeout=5.0)
            for task in done:
                if not task.cancelled() and task.exception() is not None:
                    log.error("task %s failed", task.get_name(), exc_info=task.exception())
            for task in pending:  # pragma: no cover - a bug, not a state to handle
                log.error("simulator task %s did not stop", task.get_name())
        self._task = self._video_task = None
        for w in list(self.video_clients):
            w.close()
        self.video_clients.clear()
        if self._tcp is not None:
            self._tcp.close()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(2.0):
                    await self._tcp.wait_closed()
            self._tcp = None
        for t in self._transports:
            t.close()
        self._transports.clear()

    async def __aenter__(self) -> SimServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # ---------------------------------------------------------------- ground truth / faults
    @property
    def truth(self) -> Truth:
        return self.sim.truth

    def inject_fault(self, kind: str, **params: float) -> None:
        """See :meth:`SimDrone.inject_fault`."""
        self.sim.inject_fault(kind, **params)

    # ---------------------------------------------------------------- wire
    def _navdata_request(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.sim.link_down:
            return
        self.client = addr
        self.sim.receive_navdata_request(data, self.sim.time)

    def _at(self, data: bytes) -> None:
        self.sim.receive_at(data, self.sim.time)

    async def _run(self) -> None:
        last = self.clock()
        while True:
            await asyncio.sleep(TICK_S)
            now = self.clock()
            remaining = (now - last) * self.speed
            last = now
            # Cap a stall (debugger, overloaded host) at 0.5 s of simulated time.
            remaining = min(remaining, 0.5)
            while remaining > 1e-9:
                dt = min(MAX_SUBSTEP_S, remaining)
                remaining -= dt
                self.sim.step(dt)
                packet = self.sim.navdata_due(self.sim.time)
                if packet is not None and self.client is not None and self._nav is not None:
                    transport = self._nav.transport
                    if transport is not None:
                        transport.sendto(packet, self.client)
                        self.navdata_sent += 1

    # ---------------------------------------------------------------- video
    async def _video_client(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        self.video_clients.add(writer)
        self._video_wake.set()
        try:
            while await reader.read(1024):
                pass  # clients send nothing we need
        except ConnectionError:
            pass
        finally:
            self.video_clients.discard(writer)
            writer.close()

    async def _video(self) -> None:
        """Render, encode (PaVE + H.264) and send one frame per 1/video_fps simulated seconds.

        Rendering and encoding run in a worker thread on a truth snapshot; a client that joins
        restarts the encoder so it begins on an IDR frame (with SPS/PPS)."""
        from drone.ardrone import video

        encoder: video.H264Encoder | None = None
        known: set[asyncio.StreamWriter] = set()
        next_t = self.sim.time
        while True:
            if not self.video_clients:
                self._video_wake.clear()
                await self._video_wake.wait()
                next_t = self.sim.time
            if self.video_clients - known:
                encoder = None  # someone new: start a fresh stream on an IDR
            known = set(self.video_clients)
            if self.sim.time < next_t:
                await asyncio.sleep(max(0.002, (next_t - self.sim.time) / self.speed))
                continue
            next_t += 1.0 / self.video_fps
            if next_t < self.sim.time:
                next_t = self.sim.time + 1.0 / self.video_fps  # fell behind: drop frames
            if encoder is None:
                encoder = video.H264Encoder(fps=round(self.video_fps), gop=round(self.video_fps))
            data = await asyncio.to_thread(self._frame_bytes, encoder, self.sim.truth)
            if not data:
                return
            self.video_frames_sent += 1
            for w in list(self.video_clients):
                if w.is_closing():
                    self.video_clients.discard(w)
                    continue
                w.write(data)
                if w.transport.get_write_buffer_size() > 4_000_000:
                    w.close()  # a client that does not read is dropped
                    self.video_clients.discard(w)

    def _frame_bytes(self, encoder: Any, truth: Truth) -> bytes:
        image = self.sim.render_frame(truth)
        if image is None:
            return b""
        packets = encoder.encode(image, timestamp_ms=round(truth.t_s * 1000))
        return b"".join(p.to_bytes() for p in packets)


async def run_sim(addr: str, world: str, speed: float = 1.0) -> None:
    """``uav-console sim``: serve one simulated drone until cancelled.

    Falls back to 127.0.0.1 with shifted ports when ``addr`` cannot be bound (macOS).
    """
    ports = SimPorts()
    if not loopback_usable(addr):
        addr, ports = "127.0.0.1", SimPorts.shifted(0)
    server = SimServer(addr, world, ports=ports, speed=speed)
    await server.start()
    log.warning(
        "simulated AR.Drone 2.0 on %s (navdata %d, video %d, AT %d), world %s, speed %.1f",
        addr,
        ports.navdata,
        ports.video,
        ports.at,
        world,
        speed,
    )
    try:
        await asyncio.Event().wait()
    finally:
        await server.stop()
