"""``MavlinkSimServer``: the PX4-like simulated autopilot on real sockets, as PX4 SITL serves it.

* TCP ``ADDR:5760`` — any number of clients at once (MAVSDK's ``tcpout://ADDR:5760``, mavutil's
  ``tcp:ADDR:5760``, this console's driver); each connection is its own MAVLink link.
* UDP ``ADDR:14580`` — PX4 SITL's onboard/API port: a peer that sends a datagram becomes a link
  and gets the streams back at its address (mavutil ``udpout:ADDR:14580``).
* ``udp_out`` — optionally push to a ground station listening (``udpin:0.0.0.0:14550``) as
  PX4 SITL pushes to QGroundControl on 14550.

The autopilot (``drone.mavlink.autopilot.SimAutopilot``) steps in real time × ``speed`` in
sub-steps of at most 10 ms of simulated time; its bytes for each link are written after every
turn. ``inject_fault("link_loss", duration_s=…)`` drops every byte both ways for that long.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any

from drone.mavlink.autopilot import SimAutopilot

log = logging.getLogger(__name__)

TCP_PORT = 5760  # PX4 SITL / ArduPilot SITL serial0 over TCP
UDP_PORT = 14580  # PX4 SITL onboard (API) link
MAX_SUBSTEP_S = 0.01
TICK_S = 0.005
MAX_BUFFER = 1_000_000  # a TCP client that stops reading is dropped past this


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, server: MavlinkSimServer) -> None:
        self.server = server
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.server.link_down:
            return
        self.server.autopilot.receive(("udp", addr), data)


class MavlinkSimServer:
    """See the module docstring.

    Args:
        addr: loopback address to bind (``127.0.0.9``…).
        autopilot: the simulated vehicle.
        tcp_port, udp_port: 5760 and 14580 by default; 0 picks a free port; None disables.
        udp_out: (host, port) of a listening ground station, or None.
        speed: simulated seconds per real second.
    """

    def __init__(
        self,
        addr: str,
        autopilot: SimAutopilot,
        *,
        tcp_port: int | None = TCP_PORT,
        udp_port: int | None = UDP_PORT,
        udp_out: tuple[str, int] | None = None,
        speed: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.addr = addr
        self.autopilot = autopilot
        self.tcp_port = tcp_port
        self.udp_port = udp_port
        self.udp_out = udp_out
        self.speed = speed
        self.clock = clock
        self._server: asyncio.Server | None = None
        self._udp: _Udp | None = None
        self._writers: dict[object, asyncio.StreamWriter] = {}
        self._handlers: set[asyncio.Task[Any]] = set()
        self._task: asyncio.Task[None] | None = None
        self.bytes_sent = 0

    @property
    def truth(self) -> Any:
        return self.autopilot.truth

    @property
    def link_down(self) -> bool:
        return self.autopilot.link_down

    def inject_fault(self, kind: str, **params: float) -> None:
        """See :meth:`SimAutopilot.inject_fault` (link loss included)."""
        self.autopilot.inject_fault(kind, **params)

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        if self.tcp_port is not None:
            self._server = await asyncio.start_server(self._client, self.addr, self.tcp_port)
            self.tcp_port = self._server.sockets[0].getsockname()[1]
        if self.udp_port is not None or self.udp_out is not None:
            _, proto = await loop.create_datagram_endpoint(
                lambda: _Udp(self), local_addr=(self.addr, self.udp_port or 0)
            )
            self._udp = proto
            self.udp_port = proto.transport.get_extra_info("sockname")[1] if proto.transport else 0
            if self.udp_out is not None:
                self.autopilot.connect(("udp", self.udp_out))
        self._task = asyncio.create_task(self._run(), name=f"mavlink-sim:{self.addr}")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        for w in list(self._writers.values()):
            w.close()
        if self._handlers:
            # let each client handler see its connection end, so none is left to be cancelled
            await asyncio.wait(set(self._handlers), timeout=2.0)
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                await self._server.wait_closed()
        if self._udp is not None and self._udp.transport is not None:
            self._udp.transport.close()

    async def __aenter__(self) -> MavlinkSimServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        cid: object = ("tcp", writer.get_extra_info("peername"))
        task = asyncio.current_task()
        if task is not None:
            self._handlers.add(task)
            task.add_done_callback(self._handlers.discard)
        self._writers[cid] = writer
        self.autopilot.connect(cid)
        try:
            while data := await reader.read(4096):
                if not self.link_down:
                    self.autopilot.receive(cid, data)
        except (ConnectionError, OSError):
            pass
        finally:
            self._writers.pop(cid, None)
            self.autopilot.disconnect(cid)
            writer.close()

    def _flush(self) -> None:
        ap = self.autopilot
        down = self.link_down
        for cid in list(ap.links):
            data = ap.drain(cid)
            if not data or down:
                continue
            self.bytes_sent += len(data)
            writer = self._writers.get(cid)
            if writer is not None:
                if writer.is_closing():
                    continue
                writer.write(data)
                if writer.transport.get_write_buffer_size() > MAX_BUFFER:
                    writer.close()
            elif isinstance(cid, tuple) and cid[0] == "udp" and self._udp is not None:
                transport = self._udp.transport
                if transport is not None:
                    # one datagram per MAVLink burst keeps each under the 64 KiB UDP limit
                    for i in range(0, len(data), 1400):
                        transport.sendto(data[i : i + 1400], cid[1])

    async def _run(self) -> None:
        last = self.clock()
        while True:
            await asyncio.sleep(TICK_S)
            now = self.clock()
            remaining = min((now - last) * self.speed, 0.5)
            last = now
            while remaining > 1e-9:
                dt = min(MAX_SUBSTEP_S, remaining)
                remaining -= dt
                self.autopilot.step(dt)
            self._flush()


async def run_mavlink_sim(
    addr: str,
    world: Any,
    *,
    speed: float = 1.0,
    udp_out: tuple[str, int] | None = None,
    signing_key: bytes | None = None,
) -> None:
    """``uav-console sim --protocol mavlink``: serve one simulated PX4 quadrotor until cancelled."""
    server = MavlinkSimServer(
        addr, SimAutopilot(world, signing_key=signing_key), udp_out=udp_out, speed=speed
    )
    await server.start()
    log.warning(
        "simulated PX4 quadrotor (MAVLink 2) on tcp:%s:%d and udp %s:%d, speed %.1f",
        addr,
        server.tcp_port,
        addr,
        server.udp_port,
        speed,
    )
    try:
        await asyncio.Event().wait()
    finally:
        await server.stop()
