"""The AR.Drone 2.0 client's asyncio driver: :class:`ARDroneDriver` pumps the sans-I/O
:class:`~drone.ardrone.protocol.DriverProtocol` over UDP 5554/5556 and reads video from TCP 5555.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from drone.ardrone.errors import DriverNotStartedError, VideoError
from drone.ardrone.navdata import Navdata
from drone.ardrone.protocol import (
    AT_PORT,
    NAVDATA_PORT,
    VIDEO_PORT,
    DriverConfig,
    DriverEvent,
    DriverProtocol,
    LinkLost,
    LinkRestored,
    NavdataDoubt,
    NavdataTrusted,
)

log = logging.getLogger(__name__)

# The decode time a gated decode asks room for: the longest recent one, decaying by 0.95 a frame
# (≈ 1 s at 15 fps back to the P-frames' time after an I-frame); 640×360 decodes take ≈ 2–4 ms
# here, an I-frame the longest.
DECODE_S_INITIAL = 0.004
DECODE_S_DECAY = 0.95


class _NavdataSocket(asyncio.DatagramProtocol):
    def __init__(self, driver: ARDroneDriver) -> None:
        self.driver = driver

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.driver._navdata(data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable while the drone is down: link loss handles it.
        log.debug("navdata socket error: %s", exc)


class ARDroneDriver:
    """The asyncio driver: pumps :class:`DriverProtocol` over UDP 5554/5556, video on TCP 5555.

    Command methods (``takeoff`` … ``camera``) are thread-safe (the 100 Hz controller thread calls
    ``move``) and never block; ``land`` and ``emergency`` wake the pump so they reach the wire at
    once. Events go to ``on_event`` (called in the event loop) and to the ``events`` queue (bounded;
    the oldest are dropped).

    Args:
        host: the drone's IP: ``192.168.1.1`` for a real AR.Drone 2.0, ``127.0.0.x`` for the
            simulator.
        at_port, navdata_port, video_port: the drone's ports (shifted ones on macOS).
        config: driver timing.
        video: connect to TCP video and decode frames (needs ``drone.ardrone.video``).
        clock: monotonic clock in seconds (injectable).
        on_event: callback for every :data:`DriverEvent`.
    """

    def __init__(
        self,
        host: str = "192.168.1.1",
        *,
        at_port: int = AT_PORT,
        navdata_port: int = NAVDATA_PORT,
        video_port: int = VIDEO_PORT,
        config: DriverConfig | None = None,
        video: bool = True,
        clock: Callable[[], float] = time.monotonic,
        on_event: Callable[[DriverEvent], None] | None = None,
        events_maxsize: int = 1000,
    ) -> None:
        self.host = host
        self.at_port = at_port
        self.navdata_port = navdata_port
        self.video_port = video_port
        self.protocol = DriverProtocol(config)
        self.video_enabled = video
        self.clock = clock
        self.on_event = on_event
        self.events: asyncio.Queue[DriverEvent] = asyncio.Queue(maxsize=events_maxsize)
        self.latest_frame: Any | None = None  # numpy (H, W, 3) uint8 BGR
        self.latest_frame_ms = 0  # its PaVE timestamp: capture time on the drone's clock, ms
        self.frames_decoded = 0
        self.video_errors = 0
        # Called with the expected decode time before each H.264 decode, in the decoding thread:
        # a vehicle process sets it to its control loop's wait_for_room (libavcodec holds the
        # GIL while it decodes; drone/control/loop.py).
        self.decode_gate: Callable[[float], object] | None = None
        self.decode_s = DECODE_S_INITIAL  # longest recent decode, decaying (I-frames are long)
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self._at: asyncio.DatagramTransport | None = None
        self._nav: asyncio.DatagramTransport | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._host_ip = host

    # ---------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        """Open the sockets and start the pump (and the video reader). Returns at once; wait
        for :class:`HandshakeDone` (``wait_handshake``) before flying."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._wake = asyncio.Event()
        infos = await loop.getaddrinfo(self.host, self.at_port, family=socket.AF_INET)
        self._host_ip = str(infos[0][4][0])  # navdata must come from this IP (and port 5554)
        at_t, _ = await loop.create_datagram_endpoint(
            asyncio.DatagramProtocol, remote_addr=(self.host, self.at_port)
        )
        self._at = at_t
        nav_t, _ = await loop.create_datagram_endpoint(
            lambda: _NavdataSocket(self), family=socket.AF_INET, local_addr=("0.0.0.0", 0)
        )
        self._nav = nav_t
        with self._lock:
            self.protocol.connect(self.clock())
        self._tasks.append(asyncio.create_task(self._pump(), name=f"ardrone-pump@{self.host}"))
        if self.video_enabled:
            self._tasks.append(
                asyncio.create_task(self._video(), name=f"ardrone-video@{self.host}")
            )

    async def stop(self) -> None:
        """Stop the tasks and close the sockets (idempotent). Does not land the drone."""
        for task in self._tasks:
            task.cancel()
        if self._tasks:
            done, pending = await asyncio.wait(self._tasks, timeout=5.0)
            for task in done:
                if not task.cancelled() and task.exception() is not None:
                    log.error("task %s failed", task.get_name(), exc_info=task.exception())
            for task in pending:  # pragma: no cover - a bug, not a state to handle
                log.error("driver task %s did not stop", task.get_name())
        self._tasks.clear()
        for t in (self._at, self._nav):
            if t is not None:
                t.close()
        self._at = self._nav = None

    async def __aenter__(self) -> ARDroneDriver:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # ---------------------------------------------------------------- state
    @property
    def latest_navdata(self) -> Navdata | None:
        return self.protocol.latest

    @property
    def link_up(self) -> bool:
        return self.protocol.link_up

    @property
    def handshake_done(self) -> bool:
        return self.protocol.handshake_done

    async def wait_for(self, predicate: Callable[[ARDroneDriver], bool], timeout: float) -> None:
        """Wait until ``predicate(self)`` holds (checked on every navdata/event and every 20 ms).

        Raises:
            TimeoutError: not within ``timeout`` seconds.
        """
        async with asyncio.timeout(timeout):
            while not predicate(self):
                await asyncio.sleep(0.02)

    async def wait_handshake(self, timeout: float = 5.0) -> None:
        """Wait for demo navdata. Raises TimeoutError."""
        await self.wait_for(lambda d: d.handshake_done and d.link_up, timeout)

    # ---------------------------------------------------------------- commands (thread-safe)
    def _command(self, name: str, *args: Any, urgent: bool = False) -> None:
        if self._loop is None:
            raise DriverNotStartedError(f"{name}() before start()")
        with self._lock:
            getattr(self.protocol, name)(*args)
        if urgent:
            self._poke()

    def _poke(self) -> None:
        loop, wake = self._loop, self._wake
        if loop is None or wake is None:
            return
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            wake.set()
        else:
            loop.call_soon_threadsafe(wake.set)

    def takeoff(self) -> None:
        self._command("takeoff")

    def land(self) -> None:
        """Land; reaches the wire at once, ahead of anything queued."""
        self._command("land", urgent=True)

    def emergency(self) -> None:
        """Cut the motors; reaches the wire at once, ahead of anything queued."""
        self._command("emergency", urgent=True)

    def reset(self) -> None:
        self._command("reset", urgent=True)

    def flat_trim(self) -> None:
        self._command("flat_trim")

    def hover(self) -> None:
        self._command("hover")

    def move(self, roll: float, pitch: float, gaz: float, yaw: float) -> None:
        """See :meth:`DriverProtocol.move`. Raises ValueError on NaN/inf."""
        self._command("move", roll, pitch, gaz, yaw)

    def config(self, key: str, value: str) -> None:
        self._command("config", key, value)

    def camera(self, channel: int) -> None:
        self._command("camera", channel)

    # ---------------------------------------------------------------- pump
    def _navdata(self, data: bytes, addr: tuple[str, int]) -> None:
        if addr[1] != self.navdata_port or addr[0] != self._resolved_host():
            return  # only the drone's port 5554 speaks navdata (as ARDroneLib and pyardrone)
        with self._lock:
            events = self.protocol.receive_navdata(data, self.clock())
        self._emit(events)
        if self._wake is not None:
            self._wake.set()  # a COMWDG or CTRL=5 may now be due

    def _resolved_host(self) -> str:
        return self._host_ip

    def _emit(self, events: list[DriverEvent]) -> None:
        for e in events:
            if isinstance(e, LinkLost):
                log.warning(
                    "AR.Drone %s: link lost (%.2f s without navdata)", self.host, e.silent_s
                )
            elif isinstance(e, LinkRestored):
                log.warning("AR.Drone %s: link restored", self.host)
            elif isinstance(e, NavdataDoubt):
                log.warning("AR.Drone %s: navdata in doubt: %s", self.host, e.reason)
            elif isinstance(e, NavdataTrusted):
                log.warning("AR.Drone %s: navdata consistent again", self.host)
            if self.events.full():
                self.events.get_nowait()
            self.events.put_nowait(e)
            if self.on_event is not None:
                try:
                    self.on_event(e)
                except Exception:
                    log.exception("on_event callback failed for %r", e)

    async def _pump(self) -> None:
        assert self._wake is not None
        while True:
            now = self.clock()
            with self._lock:
                inits = self.protocol.navdata_requests_due(now)
                datagrams = self.protocol.datagrams_due(now)
                events = self.protocol.poll_events(now)
                deadline = self.protocol.next_deadline(now)
            for d in inits:
                if self._nav is not None:
                    self._nav.sendto(d, (self._resolved_host(), self.navdata_port))
            for d in datagrams:
                if self._at is not None:
                    self._at.sendto(d)
            self._emit(events)
            self._wake.clear()
            delay = max(0.0, deadline - self.clock())
            if delay > 0:
                # asyncio.timeout, not wait_for: on 3.11 wait_for can swallow a cancel that races
                # with the wake-up, and stop() would then wait for this task forever.
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(delay):
                        await self._wake.wait()

    # ---------------------------------------------------------------- video
    def _decode(self, decoder: Any, frame: Any) -> list[Any]:
        """Decode one PaVE frame in a worker thread, once the decode gate lets it."""
        gate = self.decode_gate
        if gate is not None:
            gate(self.decode_s)
        t0 = time.perf_counter()
        try:
            return list(decoder.decode_packet(frame))
        finally:
            took = time.perf_counter() - t0
            self.decode_s = max(took, self.decode_s * DECODE_S_DECAY)

    async def _video(self) -> None:
        """Read PaVE frames from TCP 5555, decode H.264 in a worker thread, keep the latest."""
        try:
            from drone.ardrone import video
        except ImportError:
            log.warning("drone.ardrone.video is missing: no video from %s", self.host)
            return
        while True:
            writer: asyncio.StreamWriter | None = None
            try:
                reader, writer = await asyncio.open_connection(self.host, self.video_port)
                parser = video.PaVEParser()
                decoder = video.H264Decoder()
                while True:
                    chunk = await reader.read(65536)
                    if not chunk:
                        break
                    for frame in parser.feed(chunk):
                        images = await asyncio.to_thread(self._decode, decoder, frame)
                        for image in images:
                            self.latest_frame = image
                            self.latest_frame_ms = frame.timestamp_ms
                            self.frames_decoded += 1
            except (OSError, VideoError) as exc:
                self.video_errors += 1
                log.debug("video from %s: %s", self.host, exc)
            finally:
                if writer is not None:
                    writer.close()
            await asyncio.sleep(0.5)  # reconnect
