"""``MavlinkSimServer``: the PX4-like simulated autopilot on real sockets, as PX4 SITL serves it.

* TCP ``ADDR:5760`` — several clients at once (MAVSDK's ``tcpout://ADDR:5760``, mavutil's
  ``tcp:ADDR:5760``, this console's driver); each connection is its own MAVLink link.
* UDP ``ADDR:14580`` — PX4 SITL's onboard/API port: a peer that sends a datagram becomes a link
  and gets the streams back at its address (mavutil ``udpout:ADDR:14580``).
* ``udp_out`` — optionally push to a ground station listening (``udpin:0.0.0.0:14550``) as
  PX4 SITL pushes to QGroundControl on 14550.

Who may connect: the autopilot with a signing key obeys only signed frames; without one (the
CLI's ``--insecure``) the server listens on a loopback address only
(:class:`~drone.mavlink.errors.InsecureLinkError` otherwise). TCP connections and UDP peers go
through :class:`~drone.mavlink.admission.Admission`: at most 8 trusted links (one accepted
frame), at most 8 waiting ones (the longest waiting is closed when another arrives), and one
that sends only refused bytes for 5 s is closed — so a flood of connections costs a fixed
number of links and never displaces a ground station that has the key.

The autopilot (``drone.mavlink.sim.autopilot.SimAutopilot``) steps in real time × ``speed`` in
sub-steps of at most 10 ms of simulated time; its bytes for each link are written after every
turn. ``inject_fault("link_loss", duration_s=…)`` drops every byte both ways for that long.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drone.mavlink.admission import Admission
from drone.mavlink.errors import InsecureLinkError
from drone.mavlink.sim.autopilot import SimAutopilot

log = logging.getLogger(__name__)

TCP_PORT = 5760  # PX4 SITL / ArduPilot SITL serial0 over TCP
UDP_PORT = 14580  # PX4 SITL onboard (API) link
MAX_SUBSTEP_S = 0.01
TICK_S = 0.005
MAX_BUFFER = 1_000_000  # a TCP client that stops reading is dropped past this


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (127.0.0.0/8, ::1) or ``localhost``."""
    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip().strip("[]")).is_loopback
    except ValueError:
        return False


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, server: MavlinkSimServer) -> None:
        self.server = server
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.server.link_down:
            return
        self.server._udp_datagram(("udp", addr), data)


class MavlinkSimServer:
    """See the module docstring.

    Args:
        addr: loopback address to bind (``127.0.0.9``…).
        autopilot: the simulated vehicle.
        tcp_port, udp_port: 5760 and 14580 by default; 0 picks a free port; None disables.
        udp_out: (host, port) of a listening ground station, or None.
        speed: simulated seconds per real second.
        admission: the limits on links (default :class:`Admission`'s).

    Raises (from :meth:`start`):
        InsecureLinkError: the autopilot has no signing key and ``addr`` is not loopback.
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
        admission: Admission | None = None,
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
        self.admission = admission or Admission()
        self._configured: set[object] = set()
        self._stopping = False
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

    @property
    def signed(self) -> bool:
        return self.autopilot.signing_key is not None

    async def start(self) -> None:
        if not self.signed and not is_loopback(self.addr):
            raise InsecureLinkError(
                f"an unsigned MAVLink simulator listens on loopback only, not on {self.addr}: "
                "anyone who reaches it could arm it and cut its motors in flight; drop "
                "--insecure and give ground stations the signing key"
            )
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
                # configured by whoever started the simulator: a link outside the admission rules
                self._configured.add(("udp", self.udp_out))
                self.autopilot.connect(("udp", self.udp_out))
        self._task = asyncio.create_task(self._run(), name=f"mavlink-sim:{self.addr}")

    async def stop(self) -> None:
        self._stopping = True
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        if self._server is not None:
            self._server.close()  # no new clients from here on
        for w in list(self._writers.values()):
            w.transport.abort()  # at once: nothing queued for a client matters any more
        if self._handlers:
            # let each client handler see its connection end, so none is left to be cancelled
            await asyncio.wait(set(self._handlers), timeout=2.0)
        if self._server is not None:
            with contextlib.suppress(Exception):
                await self._server.wait_closed()
        if self._udp is not None and self._udp.transport is not None:
            self._udp.transport.close()

    async def __aenter__(self) -> MavlinkSimServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    def _close(self, cid: object, why: str) -> None:
        """Close link ``cid`` (a TCP connection or a UDP peer) for ``why``."""
        log.info("MAVLink simulator %s: closing %s: %s", self.addr, cid, why)
        self.admission.leave(cid)
        writer = self._writers.pop(cid, None)
        if writer is not None:
            writer.transport.abort()  # not close(): a client that does not read cannot hold it
        self.autopilot.disconnect(cid)

    def _arrive(self, cid: object) -> None:
        for old in self.admission.arrive(cid, self.clock()):
            self._close(old, "another client arrived while it had not proved itself")
        self.autopilot.connect(cid)

    def _heard(self, cid: object, data: bytes) -> None:
        if self.link_down:
            return
        self.autopilot.receive(cid, data)
        if cid in self._configured:
            return
        accepted = self.autopilot.accepted(cid) > 0
        if not self.admission.heard(cid, self.clock(), accepted=accepted):
            self._close(cid, f"every one of the {self.admission.max_trusted} places is taken")

    def _udp_datagram(self, cid: object, data: bytes) -> None:
        if cid not in self.autopilot.links:
            self._arrive(cid)
        self._heard(cid, data)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        cid: object = ("tcp", writer.get_extra_info("peername"))
        task = asyncio.current_task()
        if task is not None:
            self._handlers.add(task)
            task.add_done_callback(self._handlers.discard)
        if self._stopping:
            writer.transport.abort()
            return
        self._writers[cid] = writer
        self._arrive(cid)
        try:
            while data := await reader.read(4096):
                if cid not in self._writers:
                    break  # closed by the admission rules
                self._heard(cid, data)
        except (ConnectionError, OSError):
            pass
        finally:
            self.admission.leave(cid)
            if self._writers.get(cid) is writer:
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
                    writer.transport.abort()  # it stopped reading: close() would wait for it
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
            for cid in self.admission.expired(now):
                self._close(cid, "it sent nothing acceptable (unsigned, bad signature, garbage)")
            self._flush()


def signing_banner(addr: str, port: int | None, key_file: Path | None) -> list[str]:
    """What ``sim --protocol mavlink`` prints about its signing key: where it is, and how to give
    it to a ground station (never the secret itself)."""
    port = port or TCP_PORT
    lines = ["MAVLink 2 signing is on: unsigned and badly signed messages are refused."]
    if key_file is None:
        lines += [
            "  key: UAVC_MAVLINK_KEY (64 hex digits, the 32-byte secret itself)",
            "  pymavlink: m.setup_signing(bytes.fromhex(os.environ['UAVC_MAVLINK_KEY']))",
            f"  this console: uav-console serve --drone tcp:{addr}:{port} (same variable set)",
        ]
        return lines
    p = str(key_file)
    lines += [
        f"  passphrase: {p} (0600); the key is its SHA-256, as MAVProxy and Mission Planner "
        "derive a key from a passphrase",
        f'  MAVProxy: mavproxy.py --master tcp:{addr}:{port} --cmd "signing key $(cat {p})"',
        "  Mission Planner: Setup > Advanced > MAVLink Signing: add the passphrase, then Use",
        f"  pymavlink (MAVLINK20=1): m.setup_signing(hashlib.sha256(open('{p}').read()"
        ".strip().encode()).digest())",
        "  this console: UAVC_MAVLINK_KEY=$(uav-console sim --protocol mavlink --print-key "
        f"--data-dir {key_file.parent.parent}) uav-console serve --drone tcp:{addr}:{port}",
        "  MAVSDK cannot sign: for it, run the simulator with --insecure (loopback only)",
    ]
    return lines


async def run_mavlink_sim(
    addr: str,
    world: Any,
    *,
    speed: float = 1.0,
    udp_out: tuple[str, int] | None = None,
    signing_key: bytes | None = None,
    key_file: Path | None = None,
    insecure: bool = False,
    out: Callable[[str], None] = print,
) -> None:
    """``uav-console sim --protocol mavlink``: serve one simulated PX4 quadrotor until cancelled.

    Args:
        signing_key: the 32-byte key every command must be signed with; required unless
            ``insecure``.
        key_file: the passphrase file the key comes from (told to the user), or None when it
            came from ``UAVC_MAVLINK_KEY``.
        insecure: no signing; allowed on a loopback ``addr`` only.
        out: where the start-up lines go (stdout).

    Raises:
        InsecureLinkError: ``insecure`` on a non-loopback address.
        ValueError: neither a key nor ``insecure``.
    """
    if insecure:
        if not is_loopback(addr):
            raise InsecureLinkError(
                f"--insecure serves unsigned MAVLink on loopback only, and {addr} is not: "
                "anyone who reaches it could arm it and cut its motors in flight. Drop "
                "--insecure: the simulator then signs, and prints how to give ground stations "
                "its key"
            )
        signing_key = None
    elif signing_key is None:
        raise ValueError("a signing key is required unless insecure")
    ap = SimAutopilot(world, signing_key=signing_key)
    server = MavlinkSimServer(addr, ap, udp_out=udp_out, speed=speed)
    await server.start()
    name = getattr(world, "name", "") or "open field"
    out(
        f"simulated PX4 quadrotor (MAVLink 2) on tcp:{addr}:{server.tcp_port} and udp "
        f"{addr}:{server.udp_port}, world {name} (ceiling {ap.ceiling_z - ap.home[2]:.1f} m "
        f"above home), speed {speed:.1f}"
    )
    if insecure:
        out(
            "MAVLink 2 signing is OFF (--insecure): any program on this machine may arm it, "
            "take off and cut its motors"
        )
    else:
        for line in signing_banner(addr, server.tcp_port, key_file):
            out(line)
    try:
        await asyncio.Event().wait()
    finally:
        await server.stop()
