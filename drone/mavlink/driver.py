"""``MavlinkDriver``: asyncio transport around :class:`~drone.mavlink.gcs.protocol.GcsProtocol`.

Connection strings are written as mavutil and MAVProxy write them (pymavlink ``mavutil.py``
``mavlink_connection``):

* ``tcp:HOST:PORT`` — connect to a vehicle serving TCP (PX4/ArduPilot SITL on 5760); reconnects
  every second while the link is down;
* ``udpin:HOST:PORT`` — listen (``udpin:0.0.0.0:14550``, QGroundControl's port); replies go to
  the address the last datagram came from;
* ``udpout:HOST:PORT`` (also ``udp:`` as MAVProxy's ``--master=udp:`` listens, so ``udp:`` is
  ``udpin``) — send to a vehicle listening there;
* ``/dev/ttyUSB0,57600`` (or ``COM3,57600``) — a serial telemetry radio (SiK, 57600 baud by
  default) through pyserial; a reader thread hands the bytes to the event loop.

The protocol is ticked every ``tick_s`` (20 ms); its bytes are written at once. ``on_event`` gets
every protocol event (``VehicleFound``, ``CommandResult``, ``LinkLost``, ``StatusText``…).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drone.mavlink.errors import ConnectionStringError
from drone.mavlink.gcs.protocol import GcsProtocol

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string."""

    kind: str  # tcp, udpin, udpout, serial
    host: str
    port: int  # baud rate for serial

    def __str__(self) -> str:
        if self.kind == "serial":
            return f"{self.host},{self.port}"
        return f"{self.kind}:{self.host}:{self.port}"


def parse_connection(text: str) -> Endpoint:
    """Parse a mavutil/MAVProxy connection string (see the module docstring).

    Raises:
        ConnectionStringError: anything else, with what was expected.
    """
    s = text.strip()
    if s.startswith("/dev/") or s.upper().startswith("COM"):
        dev, _, baud = s.partition(",")
        try:
            rate = int(baud or "57600")
        except ValueError as exc:
            raise ConnectionStringError(f"bad baud rate in {text!r}") from exc
        return Endpoint("serial", dev, rate)
    kind, sep, rest = s.partition(":")
    kind = {"udp": "udpin", "tcpout": "tcp"}.get(kind, kind)
    host, _, port = rest.rpartition(":")
    if not sep or kind not in ("tcp", "udpin", "udpout") or not host:
        raise ConnectionStringError(
            f"{text!r} is not a MAVLink connection string; expected tcp:HOST:PORT, "
            "udpin:HOST:PORT, udpout:HOST:PORT or /dev/ttyUSB0,57600"
        )
    try:
        number = int(port)
    except ValueError as exc:
        raise ConnectionStringError(f"bad port in {text!r}") from exc
    if not 0 < number < 65536:
        raise ConnectionStringError(f"port out of range in {text!r}")
    return Endpoint(kind, host, number)


def is_connection_string(text: str) -> bool:
    try:
        parse_connection(text)
    except ConnectionStringError:
        return False
    return True


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, driver: MavlinkDriver) -> None:
        self.driver = driver

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.driver.endpoint.kind == "udpin":
            self.driver._peer = addr
        self.driver._feed(data)


class MavlinkDriver:
    """See the module docstring.

    Args:
        connection: a connection string.
        protocol: the sans-I/O core (built with defaults when None).
        on_event: called with every protocol event, in the event loop.
    """

    def __init__(
        self,
        connection: str,
        protocol: GcsProtocol | None = None,
        *,
        on_event: Callable[[Any], None] | None = None,
        tick_s: float = 0.02,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.endpoint = parse_connection(connection)
        self.protocol = protocol or GcsProtocol()
        self.on_event = on_event
        self.tick_s = tick_s
        self.clock = clock
        self.latest_frame: Any = None  # no camera over MAVLink; the runtime asks for it
        self.bytes_in = 0
        self.bytes_out = 0
        self._writer: asyncio.StreamWriter | None = None
        self._udp: asyncio.DatagramTransport | None = None
        self._peer: tuple[str, int] | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._serial: Any = None
        self._serial_stop = threading.Event()
        self._serial_thread = threading.Thread()

    async def start(self) -> None:
        ep = self.endpoint
        loop = asyncio.get_running_loop()
        if ep.kind == "serial":
            self._open_serial(loop)
        elif ep.kind in ("udpin", "udpout"):
            local = (ep.host, ep.port) if ep.kind == "udpin" else None
            transport, _ = await loop.create_datagram_endpoint(lambda: _Udp(self), local_addr=local)
            self._udp = transport
            if ep.kind == "udpout":
                self._peer = (ep.host, ep.port)
        else:
            self._tasks.append(asyncio.create_task(self._tcp(), name=f"mavlink:{ep}"))
        self._tasks.append(asyncio.create_task(self._ticker(), name=f"mavlink-tick:{ep}"))

    def _open_serial(self, loop: asyncio.AbstractEventLoop) -> None:
        try:
            import serial  # pyserial
        except ImportError as exc:  # pragma: no cover - pyserial is a dependency
            raise ConnectionStringError(f"serial links ({self.endpoint}) need pyserial") from exc
        try:
            port = serial.Serial(self.endpoint.host, self.endpoint.port, timeout=0.1)
        except (OSError, ValueError) as exc:
            raise ConnectionStringError(f"cannot open {self.endpoint}: {exc}") from exc
        self._serial = port
        self._serial_stop = threading.Event()

        def reader() -> None:
            while not self._serial_stop.is_set():
                try:
                    data = port.read(max(1, port.in_waiting))
                except (OSError, serial.SerialException):
                    break
                if data:
                    loop.call_soon_threadsafe(self._feed, data)

        self._serial_thread = threading.Thread(target=reader, name=f"mavlink-serial:{port.name}")
        self._serial_thread.daemon = True
        self._serial_thread.start()

    async def stop(self) -> None:
        if self._serial is not None:
            self._serial_stop.set()
            await asyncio.to_thread(self._serial_thread.join, 1.0)
            self._serial.close()
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks.clear()
        if self._writer is not None:
            self._writer.close()
        if self._udp is not None:
            self._udp.close()

    async def _tcp(self) -> None:
        ep = self.endpoint
        while True:
            try:
                reader, writer = await asyncio.open_connection(ep.host, ep.port)
            except OSError as exc:
                log.debug("MAVLink tcp:%s:%d: %s; retrying", ep.host, ep.port, exc)
                await asyncio.sleep(1.0)
                continue
            self._writer = writer
            try:
                while data := await reader.read(65536):
                    self._feed(data)
            except ConnectionError:
                pass
            finally:
                self._writer = None
                writer.close()
            await asyncio.sleep(0.5)

    def _feed(self, data: bytes) -> None:
        self.bytes_in += len(data)
        self.protocol.receive(data, self.clock())
        self._pump()

    def _pump(self) -> None:
        out = self.protocol.data_to_send()
        if out:
            self._write(out)
        for ev in self.protocol.events():
            if self.on_event is not None:
                try:
                    self.on_event(ev)
                except Exception:  # a listener's bug must not stop the link
                    log.exception("MAVLink event handler failed on %r", ev)

    def _write(self, data: bytes) -> None:
        if self._writer is not None and not self._writer.is_closing():
            self._writer.write(data)
            self.bytes_out += len(data)
        elif self._serial is not None:
            try:
                self._serial.write(data)  # a radio's buffer: small writes do not block
                self.bytes_out += len(data)
            except OSError as exc:
                log.warning("MAVLink %s: write failed: %s", self.endpoint, exc)
        elif self._udp is not None and self._peer is not None:
            for i in range(0, len(data), 1400):
                self._udp.sendto(data[i : i + 1400], self._peer)
            self.bytes_out += len(data)

    def flush(self) -> None:
        """Write what the protocol has now (commands go out at once, not at the next tick)."""
        self._pump()

    async def _ticker(self) -> None:
        while True:
            self.protocol.tick(self.clock())
            self._pump()
            await asyncio.sleep(self.tick_s)
