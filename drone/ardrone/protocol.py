"""The AR.Drone 2.0 client's sans-I/O core, :class:`DriverProtocol`, and its events.

:class:`DriverProtocol` owns no socket and reads no clock: feed it navdata bytes with
``receive_navdata(data, now)`` and drain ``navdata_requests_due(now)`` (datagrams for UDP 5554) and
``datagrams_due(now)`` (AT datagrams for UDP 5556). It implements, after the Developer Guide SDK 2.0
§7.1.2 and ARDroneLib ``ardrone_navdata_client.c``:

* the start-up handshake: init datagram to 5554 → bootstrap navdata → ``AT*CONFIG
  general:navdata_demo TRUE`` → wait for the command-ACK state bit 6 → ``AT*CTRL=5,0`` → demo
  navdata (``HandshakeDone``);
* an AT stream at ≥ 30 Hz (``AT*REF`` + ``AT*PCMD`` every datagram, as ARDroneLib's
  ``ardrone_at_set_progress_cmd`` loop does) so the drone's 2 s command watchdog never trips,
  plus ``AT*COMWDG`` whenever navdata shows the COM-watchdog bit 30;
* ``emergency`` and ``land`` jump the queue: the next datagram is due at once and starts with the
  ``AT*REF`` that carries them, before any queued one-shot command (DESIGN §5);
* link loss when no navdata arrives for ``link_timeout_s`` (``LinkLost``), re-init datagrams
  while lost, ``LinkRestored`` (and a fresh handshake if the drone came back in bootstrap);
* plausibility of the unauthenticated navdata (``drone/ardrone/plausibility.py``): packets off
  the drone's numbering are dropped, an implausible battery reading is not believed, and the
  driver says when it doubts the stream (``NavdataDoubt``) and when it trusts it again
  (``NavdataTrusted``).

The asyncio driver that pumps it over sockets is ``drone/ardrone/driver.py``.
"""

from __future__ import annotations

import enum
import logging
import math
from collections import deque
from dataclasses import dataclass, field

from drone.ardrone import at
from drone.ardrone.errors import DriverNotStartedError, NavdataError
from drone.ardrone.navdata import DroneState, Navdata, decode_navdata, navdata_init_datagram
from drone.ardrone.plausibility import NavdataPlausibility, PlausibilityConfig

AT_PORT = 5556
NAVDATA_PORT = 5554
VIDEO_PORT = 5555

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DriverConfig:
    """Timing of the client; defaults follow ARDroneLib and DESIGN §5."""

    at_period_s: float = 0.03  # ≥ 30 Hz; ARDroneLib sends every 30 ms (Developer Guide §6.1)
    link_timeout_s: float = 0.5  # no navdata this long -> LinkLost (DESIGN §5)
    init_retry_s: float = 0.5  # resend the navdata init datagram while nothing arrives
    config_retry_s: float = 0.5  # resend a CONFIG whose ACK bit has not appeared
    emergency_hold_s: float = 1.0  # keep the emergency bit this long if navdata never confirms
    # sequence-jump and battery-slope checks on unauthenticated navdata (plausibility.py)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)


class LinkState(enum.Enum):
    """Where the client is in the navdata handshake (ardrone_navdata_client.c)."""

    IDLE = "idle"  # connect() not called yet
    WAITING = "waiting"  # init datagram sent, no navdata yet
    CONFIGURING = "configuring"  # CONFIG general:navdata_demo sent, waiting for the ACK bit
    ACKING = "acking"  # AT*CTRL=5 sent, waiting for the ACK bit to clear
    READY = "ready"  # demo navdata flowing
    LOST = "lost"  # navdata stopped for link_timeout_s


@dataclass(frozen=True)
class NavdataReceived:
    navdata: Navdata
    now: float


@dataclass(frozen=True)
class HandshakeDone:
    now: float


@dataclass(frozen=True)
class LinkLost:
    now: float
    silent_s: float  # time since the last navdata


@dataclass(frozen=True)
class LinkRestored:
    now: float


@dataclass(frozen=True)
class NavdataRejected:
    """A datagram on 5554 that did not decode, or failed a plausibility check (dropped, or its
    battery held at the last plausible level; the link state is unchanged)."""

    now: float
    error: str


@dataclass(frozen=True)
class NavdataDoubt:
    """The navdata stream is no longer trusted: packets off the drone's numbering or battery
    readings no discharge explains keep coming (a sensor fault, or someone else sending)."""

    now: float
    reason: str


@dataclass(frozen=True)
class NavdataTrusted:
    """The stream is consistent again (nothing suspicious for ``trust_again_s``)."""

    now: float


DriverEvent = (
    NavdataReceived
    | HandshakeDone
    | LinkLost
    | LinkRestored
    | NavdataRejected
    | NavdataDoubt
    | NavdataTrusted
)


def _fraction(name: str, value: float) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number in [-1, 1], got {value!r}")
    return max(-1.0, min(1.0, float(value)))


class DriverProtocol:
    """Sans-I/O AR.Drone client core. All times are seconds on the caller's clock.

    Typical pump (what :class:`ARDroneDriver` and ``drone.sim.link.InMemoryLink`` do)::

        proto.connect(now)
        loop:
            for d in proto.navdata_requests_due(now): send d to (drone, 5554)
            for d in proto.datagrams_due(now): send d to (drone, 5556)
            on navdata bytes: events += proto.receive_navdata(data, now)
            events += proto.poll_events(now)
            sleep until proto.next_deadline(now)

    Command methods (``takeoff``, ``land``, ``emergency``, ``reset``, ``flat_trim``, ``hover``,
    ``move``, ``config``, ``camera``) only change what the next datagrams carry; they never block.
    Timing lives in ``options`` (a :class:`DriverConfig`); ``config(key, value)`` is the command
    that writes a drone configuration key.
    """

    def __init__(self, config: DriverConfig | None = None) -> None:
        self.options = config or DriverConfig()
        self.encoder = at.ATEncoder()
        self.state = LinkState.IDLE
        self.latest: Navdata | None = None  # last navdata accepted
        self.plausibility = NavdataPlausibility(self.options.plausibility)
        self.last_navdata_at: float | None = None
        self._ref = at.REF_BASE
        self._pcmd = at.Pcmd.hover()
        self._urgent = False  # the next datagram is due now (land / emergency)
        self._emergency_until: float | None = None  # holding the emergency bit until then
        self._emergency_target: bool | None = None  # EMERGENCY state we are waiting to see
        self._sent_emergency_bit = False  # the last AT*REF sent had the emergency bit
        self._edge_first = False  # send the bit cleared once before holding it again
        self._queue: deque[at.ATCommand] = deque()  # one-shot commands, FIFO
        self._comwdg = False
        self._pending_config: at.Config | None = None  # waiting for the ACK bit
        self._config_sent_at = -math.inf
        self._ack_sent = False
        self._next_at = -math.inf
        self._next_init = -math.inf
        self._events: list[DriverEvent] = []
        self._handshake_done = False

    # ---------------------------------------------------------------- lifecycle
    def connect(self, now: float) -> None:
        """Start (or restart) the session: sequence 1, init datagram due now, AT stream due now."""
        self.encoder.reset()
        self.state = LinkState.WAITING
        self.latest = None
        self.last_navdata_at = None
        self._handshake_done = False
        self._pending_config = None
        self._ack_sent = False
        self._next_at = now
        self._next_init = now

    @property
    def handshake_done(self) -> bool:
        """True once demo navdata flows (stays True across a link loss that needs no handshake)."""
        return self._handshake_done

    @property
    def link_up(self) -> bool:
        return self.state in (LinkState.CONFIGURING, LinkState.ACKING, LinkState.READY)

    @property
    def latest_navdata(self) -> Navdata | None:
        """Same as ``latest`` (the name ``ARDroneDriver`` uses, so code can take either)."""
        return self.latest

    # ---------------------------------------------------------------- commands
    def takeoff(self) -> None:
        """Hold the take-off bit in AT*REF (level-triggered on the drone, §6.6)."""
        self._require_started()
        self._ref = at.REF_BASE | at.REF_TAKEOFF_BIT

    def land(self) -> None:
        """Clear the take-off bit and hover; jumps the queue (next datagram due at once)."""
        self._require_started()
        self._ref = at.REF_BASE
        self._pcmd = at.Pcmd.hover()
        self._emergency_until = None
        self._urgent = True

    def emergency(self) -> None:
        """Cut the motors: emergency bit in the very next datagram, ahead of everything queued.

        The bit is a toggle on the drone, so it is not sent when navdata already shows EMERGENCY.
        """
        self._require_started()
        if self.latest is not None and self.latest.state & DroneState.EMERGENCY:
            return
        self._hold_emergency_bit(target=True)

    def reset(self) -> None:
        """Leave the emergency state (toggle the emergency bit) when navdata shows it."""
        self._require_started()
        if self.latest is not None and self.latest.state & DroneState.EMERGENCY:
            self._hold_emergency_bit(target=False)

    def flat_trim(self) -> None:
        """Queue AT*FTRIM (only meaningful when landed)."""
        self._require_started()
        self._queue.append(at.Ftrim())

    def hover(self) -> None:
        """PCMD with the progressive flag cleared: the drone holds position on its own."""
        self._require_started()
        self._pcmd = at.Pcmd.hover()

    def move(self, roll: float, pitch: float, gaz: float, yaw: float) -> None:
        """Progressive command; each value clamped to [-1, 1]. All zero is sent as hover.

        roll < 0 left, pitch < 0 forward, gaz > 0 up, yaw > 0 clockwise (fractions of
        euler_angle_max, control_vz_max, control_yaw).

        Raises:
            ValueError: a value is NaN or infinite.
        """
        self._require_started()
        r = _fraction("roll", roll)
        p = _fraction("pitch", pitch)
        g = _fraction("gaz", gaz)
        y = _fraction("yaw", yaw)
        if r == p == g == y == 0.0:
            self._pcmd = at.Pcmd.hover()
        else:
            self._pcmd = at.Pcmd(at.PCMD_PROGRESSIVE, r, p, g, y)

    def config(self, key: str, value: str) -> None:
        """Queue an AT*CONFIG write; the ACK bit is acknowledged with AT*CTRL=5 automatically.

        Raises:
            ATEncodeError: key or value contains a quote, CR/LF or non-ASCII.
        """
        self._require_started()
        cmd = at.Config(key, value)
        cmd.args()  # validate now, not at send time
        self._queue.append(cmd)

    def camera(self, channel: int) -> None:
        """Select the video channel (0 front, 1 bottom; ``video:video_channel``)."""
        if channel not in (0, 1, 2, 3):
            raise ValueError(f"video channel must be 0..3, got {channel}")
        self.config("video:video_channel", str(channel))

    def _hold_emergency_bit(self, target: bool) -> None:
        self._ref = (self._ref & ~at.REF_TAKEOFF_BIT) | at.REF_EMERGENCY_BIT
        self._pcmd = at.Pcmd.hover()
        self._emergency_target = target
        self._emergency_until = math.inf  # set to now + hold on the first send
        # The drone toggles on the bit's rising edge: if the last REF sent still had it (a reset
        # right after the emergency was seen), one REF without it must go first.
        self._edge_first = self._sent_emergency_bit
        self._urgent = True

    def _require_started(self) -> None:
        if self.state is LinkState.IDLE:
            raise DriverNotStartedError("call connect(now) before sending commands")

    # ---------------------------------------------------------------- output
    def navdata_requests_due(self, now: float) -> list[bytes]:
        """Datagrams for UDP 5554: the init datagram, repeated while no navdata arrives."""
        self._check_link(now)
        if self.state not in (LinkState.WAITING, LinkState.LOST) or now < self._next_init:
            return []
        self._next_init = now + self.options.init_retry_s
        return [navdata_init_datagram()]

    def datagrams_due(self, now: float) -> list[bytes]:
        """AT datagrams for UDP 5556 due at ``now``: one every ``at_period_s``, or at once after
        ``land``/``emergency``. Each starts with AT*REF then AT*PCMD, then AT*COMWDG if asked, then
        as many queued one-shot commands as fit 1024 bytes."""
        self._check_link(now)
        if self.state is LinkState.IDLE or (not self._urgent and now < self._next_at):
            return []
        self._urgent = False
        self._next_at = max(self._next_at + self.options.at_period_s, now)
        if self._next_at <= now:
            self._next_at = now + self.options.at_period_s
        ref = self._ref
        if self._edge_first:
            self._edge_first = False
            ref &= ~at.REF_EMERGENCY_BIT
            self._urgent = True  # the bit itself follows at once
        elif self._emergency_until is not None:
            if self._emergency_until == math.inf:
                self._emergency_until = now + self.options.emergency_hold_s
            elif now >= self._emergency_until:
                self._release_emergency_bit()
                ref = self._ref
        self._sent_emergency_bit = bool(ref & at.REF_EMERGENCY_BIT)
        commands: list[at.ATCommand] = [at.Ref(ref), self._pcmd]
        if self._comwdg:
            commands.append(at.Comwdg())
            self._comwdg = False
        commands.extend(self._handshake_commands(now))
        out = b"".join(self.encoder.encode(c) for c in commands)
        while self._queue and self._pending_config is None:
            cmd = self._queue[0]
            wire = at.encode_command(cmd, self.encoder.next_seq)
            if len(out) + len(wire) > at.MAX_DATAGRAM:
                break
            self._queue.popleft()
            out += self.encoder.encode(cmd)
            if isinstance(cmd, at.Config):
                self._pending_config = cmd
                self._config_sent_at = now
        return [out]

    def _handshake_commands(self, now: float) -> list[at.ATCommand]:
        """CONFIG resend / CTRL=5 acknowledgement for the pending config write."""
        nav = self.latest
        if self._pending_config is None or nav is None:
            return []
        acked = bool(nav.state & DroneState.COMMAND)
        if acked and not self._ack_sent:
            self._ack_sent = True
            return [at.Ctrl(at.CTRL_ACK, 0)]
        if not acked and self._ack_sent:
            # ACK bit cleared after our CTRL=5: the write is done.
            self._pending_config = None
            self._ack_sent = False
            return []
        if not acked and now - self._config_sent_at >= self.options.config_retry_s:
            self._config_sent_at = now
            return [self._pending_config]
        if acked and self._ack_sent and now - self._config_sent_at >= self.options.config_retry_s:
            self._config_sent_at = now
            return [at.Ctrl(at.CTRL_ACK, 0)]
        return []

    def _release_emergency_bit(self) -> None:
        self._ref = at.REF_BASE
        self._emergency_until = None
        self._emergency_target = None

    def next_deadline(self, now: float) -> float:
        """The earliest time something will be due (for the asyncio driver's sleep)."""
        deadlines = [self._next_at]
        if self.state in (LinkState.WAITING, LinkState.LOST):
            deadlines.append(self._next_init)
        if self.last_navdata_at is not None and self.state is not LinkState.LOST:
            deadlines.append(self.last_navdata_at + self.options.link_timeout_s)
        return now if self._urgent else max(now, min(deadlines))

    # ---------------------------------------------------------------- input
    def receive_navdata(self, data: bytes, now: float) -> list[DriverEvent]:
        """Feed one datagram from UDP 5554; returns the events it (and elapsed time) caused.

        Bad datagrams give a :class:`NavdataRejected` event and are otherwise ignored. Packets
        off the followed numbering (a lower or repeated sequence, a far jump) are dropped with a
        :class:`NavdataRejected`, unless the drone's own evidence says its numbering restarted
        (``drone/ardrone/plausibility.py``); after a lost link the next stream is followed
        whatever its numbering. Enough suspicious packets give :class:`NavdataDoubt`.
        """
        events = self._drain(now)
        if self.state is LinkState.IDLE:
            return events
        try:
            nav = decode_navdata(data)
        except NavdataError as exc:
            events.append(NavdataRejected(now, str(exc)))
            return events
        if self.latest is None or self.state is LinkState.LOST:
            # the first stream, or one after a silence longer than the link timeout
            self.plausibility.reset()
        # Navdata is unauthenticated: a forged packet must neither take the stream's place nor
        # fake a battery collapse (drone/ardrone/plausibility.py).
        doubted = self.plausibility.doubt
        verdict = self.plausibility.check(nav, now)
        if verdict.reason is not None and (verdict.suspicious or verdict.navdata is None):
            events.append(NavdataRejected(now, verdict.reason))
        elif verdict.reason is not None:
            log.info("navdata: %s", verdict.reason)
        if self.plausibility.doubt and not doubted:
            events.append(NavdataDoubt(now, self.plausibility.doubt))
        if verdict.navdata is None:
            return events
        nav = verdict.navdata
        was_lost = self.state is LinkState.LOST
        self.latest = nav
        self.last_navdata_at = now
        if was_lost:
            events.append(LinkRestored(now))
            self.encoder.reset()  # seq 1 resets the drone's counter (§6.1), safe after a reboot
            self.state = LinkState.WAITING
        if nav.state & DroneState.COM_WATCHDOG:
            self._comwdg = True
        if self._emergency_target is not None and bool(nav.state & DroneState.EMERGENCY) == (
            self._emergency_target
        ):
            self._release_emergency_bit()
        self._advance_handshake(nav, now, events)
        events.append(NavdataReceived(nav, now))
        return events

    def _advance_handshake(self, nav: Navdata, now: float, events: list[DriverEvent]) -> None:
        bootstrap = bool(nav.state & DroneState.NAVDATA_BOOTSTRAP)
        if self.state is LinkState.WAITING:
            if bootstrap or nav.demo is None:
                self._queue.appendleft(at.Config("general:navdata_demo", "TRUE"))
                self.state = LinkState.CONFIGURING
            else:
                self._ready(now, events)
        elif self.state in (LinkState.CONFIGURING, LinkState.ACKING):
            if self._ack_sent:
                self.state = LinkState.ACKING
            if not bootstrap and nav.demo is not None and self._pending_config is None:
                self._ready(now, events)
        elif self.state is LinkState.READY and bootstrap:
            # The drone rebooted under us: redo the handshake.
            self._handshake_done = False
            self.state = LinkState.WAITING
            self._advance_handshake(nav, now, events)

    def _ready(self, now: float, events: list[DriverEvent]) -> None:
        self.state = LinkState.READY
        if not self._handshake_done:
            self._handshake_done = True
            events.append(HandshakeDone(now))

    def poll_events(self, now: float) -> list[DriverEvent]:
        """Events caused by time alone (``LinkLost``); call it every loop turn."""
        return self._drain(now)

    def _drain(self, now: float) -> list[DriverEvent]:
        self._check_link(now)
        doubted = self.plausibility.doubt
        self.plausibility.poll(now)
        if doubted and not self.plausibility.doubt:
            self._events.append(NavdataTrusted(now))
        events, self._events = self._events, []
        return events

    def _check_link(self, now: float) -> None:
        if self.state in (LinkState.IDLE, LinkState.LOST):
            return
        since = self.last_navdata_at if self.last_navdata_at is not None else None
        if since is None:
            return  # never had navdata: WAITING keeps re-sending the init datagram
        silent = now - since
        if silent >= self.options.link_timeout_s:
            self.state = LinkState.LOST
            if self._pending_config is not None:  # unacknowledged: send it again after recovery
                self._queue.appendleft(self._pending_config)
            self._pending_config = None
            self._ack_sent = False
            self._next_init = now
            self._events.append(LinkLost(now, silent))
