"""``GcsProtocol``: the console's side of a MAVLink 2 link, sans-I/O (bytes and ``now`` in, bytes
and typed events out), as a ground station speaks to PX4 or ArduPilot.

What it does (mavlink.io "Microservices"):

* **Heartbeat** as ``MAV_TYPE_GCS`` at 1 Hz (the autopilot's data-link-loss failsafe watches it).
* **Discovery**: the first heartbeat from an autopilot component (not a GCS, autopilot not
  INVALID) picks the vehicle (or only ``target_system`` when given); another system id on the
  same link is ignored and reported once (:class:`OtherVehicle`).
* **Message intervals**: on discovery, ``MAV_CMD_SET_MESSAGE_INTERVAL`` for the streams the
  console needs, and ``MAV_CMD_REQUEST_MESSAGE`` for HOME_POSITION.
* **Command protocol**: COMMAND_LONG/COMMAND_INT with COMMAND_ACK; one command per command id in
  flight (a second with the same id waits its turn, an identical one already waiting is not
  queued twice); retries after ``command_timeout_s`` with ``confirmation`` incremented (so the
  vehicle can tell a retransmission from a new command); ``MAV_RESULT_IN_PROGRESS`` keeps a
  command alive and reports its progress. A refusal's reason is the STATUSTEXT the vehicle sent
  just before (PX4 and ArduPilot both explain denials that way).
* **Mission protocol** (upload): MISSION_COUNT → MISSION_REQUEST_INT → MISSION_ITEM_INT … →
  MISSION_ACK, with retransmission on timeout.
* **Offboard setpoints**: SET_POSITION_TARGET_LOCAL_NED streamed at ``setpoint_hz`` while a
  velocity or position target is held; releasing a velocity target sends zero velocity before
  the stream stops.
* **Link watchdog**: no heartbeat from the vehicle for ``link_timeout_s`` (1.5 s) →
  :class:`LinkLost` naming the autopilot's own failsafe (PX4: NAV_DLL_ACT after COM_DL_LOSS_T;
  ArduPilot: FS_GCS_ENABLE), read from the vehicle's parameters when it answered.
* **Plausibility**: a frame that decodes is still the vehicle's word only: a position,
  attitude, home or parameter value that is NaN or infinite, or a latitude/longitude off the
  globe, is dropped whole and counted (``codec.rejected["implausible"]``), so telemetry and
  the snapshot the fleet reads hold finite numbers; an unknown enum value (a MISSION_ACK
  result this dialect does not name) is reported by its number.

Use: ``receive(data, now)``; ``tick(now)`` every 10–50 ms; ``data_to_send()``; ``events()``.
"""

from __future__ import annotations

import collections
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from drone.mavlink.codec import Codec, Message, mav, signing_timestamp
from drone.mavlink.modes import custom_mode, intent_mode, mode_name

GCS_SYSTEM_ID = 255  # QGroundControl's and MAVProxy's default
GCS_COMPONENT_ID = mav.MAV_COMP_ID_MISSIONPLANNER  # 190
HEARTBEAT_PERIOD_S = 1.0  # MAVLink "Heartbeat/Connection Protocol": 1 Hz
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: kill motors even in the air

# Streams requested on discovery (Hz).
STREAMS_HZ = {
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    mav.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mav.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mav.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0,
    mav.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
    mav.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}
RESULT_NAMES = {v.name.removeprefix("MAV_RESULT_"): k for k, v in mav.enums["MAV_RESULT"].items()}
_RESULTS = {k: v.name.removeprefix("MAV_RESULT_") for k, v in mav.enums["MAV_RESULT"].items()}
_COMMANDS = {k: v.name.removeprefix("MAV_CMD_") for k, v in mav.enums["MAV_CMD"].items()}
_LANDED = {
    mav.MAV_LANDED_STATE_UNDEFINED: "UNDEFINED",
    mav.MAV_LANDED_STATE_ON_GROUND: "ON_GROUND",
    mav.MAV_LANDED_STATE_IN_AIR: "IN_AIR",
    mav.MAV_LANDED_STATE_TAKEOFF: "TAKEOFF",
    mav.MAV_LANDED_STATE_LANDING: "LANDING",
}
AUTOPILOTS = {mav.MAV_AUTOPILOT_PX4: "PX4", mav.MAV_AUTOPILOT_ARDUPILOTMEGA: "ArduPilot"}
_MISSION_RESULTS = {
    k: v.name.removeprefix("MAV_MISSION_") for k, v in mav.enums["MAV_MISSION_RESULT"].items()
}
# The float fields the telemetry (or the failsafe text) takes from each message. None of them
# has a "NaN means unknown" meaning in the MAVLink definitions, so a non-finite value is damage
# or forgery, and the message is dropped (see "Plausibility" in the module docstring).
_FLOAT_FIELDS = {
    "LOCAL_POSITION_NED": ("x", "y", "z", "vx", "vy", "vz"),
    "ATTITUDE": ("roll", "pitch", "yaw"),
    "HOME_POSITION": ("x", "y", "z"),
    "PARAM_VALUE": ("param_value",),
}
# The degE7 latitude/longitude fields of each message: on the globe or dropped.
_LAT_LON_FIELDS = {
    "GLOBAL_POSITION_INT": ("lat", "lon"),
    "HOME_POSITION": ("latitude", "longitude"),
}


def implausible(msg: Message) -> str | None:
    """Why a decoded message cannot be telemetry (a non-finite value, a point off the globe),
    or None when it can."""
    kind = msg.get_type()
    for name in _FLOAT_FIELDS.get(kind, ()):
        value = getattr(msg, name)
        if not math.isfinite(value):
            return f"{kind}.{name} is {value}"
    lat_lon = _LAT_LON_FIELDS.get(kind)
    if lat_lon is not None:
        lat, lon = (getattr(msg, name) for name in lat_lon)
        if not (-90e7 <= lat <= 90e7 and -180e7 <= lon <= 180e7):
            return f"{kind} at {lat / 1e7}°, {lon / 1e7}° is off the globe"
    return None


def command_name(command: int) -> str:
    """``MAV_CMD_NAV_TAKEOFF`` → ``"NAV_TAKEOFF"``."""
    return str(_COMMANDS.get(command, f"COMMAND_{command}"))


# ---------------------------------------------------------------------- events
@dataclass(frozen=True)
class VehicleFound:
    system_id: int
    autopilot: str
    vehicle_type: int


@dataclass(frozen=True)
class OtherVehicle:
    """A heartbeat from another system id on the same link (ignored)."""

    system_id: int


@dataclass(frozen=True)
class LinkLost:
    age_s: float
    failsafe: str  # what the autopilot will do, in words


@dataclass(frozen=True)
class LinkRestored:
    pass


@dataclass(frozen=True)
class CommandResult:
    """The end of one command: ``result`` is ACCEPTED, DENIED, …, or NO_ANSWER."""

    token: int
    command: str
    result: str
    reason: str | None = None
    cause: CommandResult | None = None  # NOT_SENT: the earlier command of the chain that failed

    @property
    def ok(self) -> bool:
        return self.result == "ACCEPTED"


@dataclass(frozen=True)
class CommandProgress:
    token: int
    command: str
    progress_pct: int


@dataclass(frozen=True)
class StatusText:
    severity: int
    text: str


@dataclass(frozen=True)
class MissionResult:
    ok: bool
    count: int
    detail: str


@dataclass(frozen=True)
class MissionItemReached:
    seq: int


@dataclass(frozen=True)
class Telemetry:
    """What the vehicle last told (immutable). NaN where never heard."""

    system_id: int = 0
    autopilot: str = ""
    autopilot_id: int = 0
    mode: str = ""
    armed: bool = False
    system_status: int = 0
    landed_state: str = "UNDEFINED"
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    alt_amsl_m: float = math.nan
    rel_alt_m: float = math.nan
    vn: float = 0.0
    ve: float = 0.0
    vd: float = 0.0
    local_ned: tuple[float, float, float] | None = None
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    heading_rad: float = 0.0  # clockwise from north
    battery_pct: float = math.nan
    voltage_v: float = math.nan
    gps_fix: int = 0
    satellites: int = 0
    eph_m: float = math.nan
    sensors_ok: bool = False
    home: tuple[float, float, float] | None = None  # lat, lon, alt AMSL
    home_local: tuple[float, float, float] | None = None
    mission_current: int = -1
    last_heartbeat_t: float | None = None
    last_message_t: float | None = None


# ---------------------------------------------------------------------- commands
@dataclass
class _Command:
    token: int
    command: int
    params: tuple[float, ...]  # 7 values
    use_int: bool = False
    frame: int = mav.MAV_FRAME_GLOBAL_INT
    attempts: int = 0
    sent_t: float = -math.inf
    progress_t: float | None = None
    then: list[_Command] = field(default_factory=list)  # sent after this one is ACCEPTED


@dataclass
class _Upload:
    items: list[Message]
    started_t: float
    last_t: float
    tries: int = 0
    sent_count: bool = False


class GcsProtocol:
    """See the module docstring.

    ``signing_key`` signs every frame and accepts only signed ones; ``signing_clock`` (Unix
    time) is read for the signing timestamps only, which start at it and are kept at least at
    it (``Codec.keep_up``), so the vehicle's "new stream at most a minute old" check passes.
    """

    def __init__(
        self,
        *,
        target_system: int | None = None,
        system_id: int = GCS_SYSTEM_ID,
        component_id: int = GCS_COMPONENT_ID,
        signing_key: bytes | None = None,
        signing_clock: Callable[[], float] = time.time,
        link_timeout_s: float = 1.5,
        command_timeout_s: float = 1.0,
        retries: int = 3,
        setpoint_hz: float = 10.0,
        request_streams: bool = True,
    ) -> None:
        self.signing_clock = signing_clock
        self.codec = Codec(
            system_id,
            component_id,
            signing_key=signing_key,
            initial_timestamp=signing_timestamp(signing_clock()) if signing_key else None,
        )
        self.m = self.codec.mav
        self.target_system = target_system
        self.target_component = mav.MAV_COMP_ID_AUTOPILOT1
        self.link_timeout_s = link_timeout_s
        self.command_timeout_s = command_timeout_s
        self.retries = retries
        self.setpoint_period_s = 1.0 / setpoint_hz
        self.request_streams = request_streams
        self.telemetry = Telemetry()
        self.link_ok = False
        self.params: dict[str, float] = {}
        self.commands_sent = 0  # COMMAND_LONG/INT frames written, retries included
        self._out = bytearray()
        self._events: list[Any] = []
        self._next_hb = -math.inf
        self._token = 0
        self._inflight: dict[int, _Command] = {}
        self._waiting: dict[int, collections.deque[_Command]] = collections.defaultdict(
            collections.deque
        )
        self._others: set[int] = set()
        self._texts: collections.deque[tuple[float, StatusText]] = collections.deque(maxlen=8)
        self._now = 0.0
        self._setpoint: tuple[str, tuple[float, ...]] | None = None  # ("vel"|"pos", values)
        self._next_sp = -math.inf
        self._zero_burst = 0
        self._upload: _Upload | None = None
        self._chunks: tuple[int, int, int, str] | None = None  # (id, severity, last seq, text)

    # ------------------------------------------------------------------ plumbing
    def data_to_send(self) -> bytes:
        data = bytes(self._out)
        self._out.clear()
        return data

    def events(self) -> list[Any]:
        ev, self._events = self._events, []
        return ev

    def _send(self, msg: Message) -> None:
        self._out += self.codec.encode(msg)

    @property
    def connected(self) -> bool:
        return self.telemetry.system_id != 0 and self.link_ok

    # ------------------------------------------------------------------ input
    def receive(self, data: bytes, now: float) -> None:
        self._now = now
        for msg in self.codec.feed(data):
            self._handle(msg, now)

    def _handle(self, msg: Message, now: float) -> None:  # noqa: C901
        """Fold one received message into the telemetry and the pending exchanges.

        Complexity: one short branch per MAVLink message type a ground station reads, flat on
        purpose so that each message's handling reads in one place."""
        kind = msg.get_type()
        src = msg.get_srcSystem()
        t = self.telemetry
        if kind == "HEARTBEAT":
            if msg.type == mav.MAV_TYPE_GCS or msg.autopilot == mav.MAV_AUTOPILOT_INVALID:
                return
            if t.system_id == 0 and self.target_system in (None, src):
                self._discovered(msg, now)
                t = self.telemetry
            if src != t.system_id:
                if src not in self._others:
                    self._others.add(src)
                    self._events.append(OtherVehicle(src))
                return
            if msg.get_srcComponent() != self.target_component:
                return
            armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
            self.telemetry = replace(
                t,
                mode=mode_name(msg.autopilot, msg.custom_mode),
                armed=armed,
                system_status=msg.system_status,
                last_heartbeat_t=now,
                last_message_t=now,
            )
            if not self.link_ok:
                self.link_ok = True
                if t.last_heartbeat_t is not None:
                    self._events.append(LinkRestored())
            return
        if t.system_id == 0 or src != t.system_id:
            return
        if implausible(msg) is not None:
            self.codec.rejected["implausible"] += 1
            return
        t = replace(t, last_message_t=now)
        if kind == "GLOBAL_POSITION_INT":
            t = replace(
                t,
                lat_deg=msg.lat / 1e7,
                lon_deg=msg.lon / 1e7,
                alt_amsl_m=msg.alt / 1000.0,
                rel_alt_m=msg.relative_alt / 1000.0,
                vn=msg.vx / 100.0,
                ve=msg.vy / 100.0,
                vd=msg.vz / 100.0,
            )
        elif kind == "LOCAL_POSITION_NED":
            t = replace(t, local_ned=(msg.x, msg.y, msg.z), vn=msg.vx, ve=msg.vy, vd=msg.vz)
        elif kind == "ATTITUDE":
            t = replace(t, roll_rad=msg.roll, pitch_rad=msg.pitch, heading_rad=msg.yaw)
        elif kind == "SYS_STATUS":
            need = (
                mav.MAV_SYS_STATUS_SENSOR_3D_GYRO
                | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                | mav.MAV_SYS_STATUS_SENSOR_GPS
            )
            ok = (msg.onboard_control_sensors_health & need) == need
            pct = msg.battery_remaining if msg.battery_remaining >= 0 else t.battery_pct
            t = replace(t, sensors_ok=ok, voltage_v=msg.voltage_battery / 1000.0, battery_pct=pct)
        elif kind == "BATTERY_STATUS":
            if msg.battery_remaining >= 0:
                t = replace(t, battery_pct=float(msg.battery_remaining))
        elif kind == "EXTENDED_SYS_STATE":
            t = replace(t, landed_state=_LANDED.get(msg.landed_state, "UNDEFINED"))
        elif kind == "GPS_RAW_INT":
            eph = msg.eph / 100.0 if msg.eph != 65535 else math.nan
            t = replace(t, gps_fix=msg.fix_type, satellites=msg.satellites_visible, eph_m=eph)
        elif kind == "HOME_POSITION":
            t = replace(
                t,
                home=(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0),
                home_local=(msg.x, msg.y, msg.z),
            )
        elif kind == "MISSION_CURRENT":
            t = replace(t, mission_current=msg.seq)
        elif kind == "MISSION_ITEM_REACHED":
            self._events.append(MissionItemReached(msg.seq))
        elif kind == "STATUSTEXT":
            self._on_statustext(msg, now)
        elif kind == "COMMAND_ACK":
            self._on_ack(msg, now)
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._on_mission_request(msg, now)
        elif kind == "MISSION_ACK":
            self._on_mission_ack(msg)
        elif kind == "PARAM_VALUE":
            pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            self.params[pid.rstrip("\x00")] = float(msg.param_value)
        self.telemetry = t

    def _on_statustext(self, msg: Message, now: float) -> None:
        """One STATUSTEXT, or a chunk of a longer one: MAVLink 2 splits texts over 50 characters
        into chunks with the same ``id`` and rising ``chunk_seq``; the last is shorter than 50
        (null-terminated). A chunk of another id, or a gap, flushes what was gathered."""
        raw = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
        text = raw.split("\x00", 1)[0]
        ended = len(raw.rstrip("\x00")) < 50 or "\x00" in raw
        text_id = getattr(msg, "id", 0)
        if text_id == 0:
            self._emit_text(msg.severity, text, now)
            return
        pending = self._chunks
        if pending is not None and (pending[0] != text_id or msg.chunk_seq != pending[2] + 1):
            self._emit_text(pending[1], pending[3], now)  # incomplete: say what arrived
            pending = None
        if pending is None:
            pending = (text_id, msg.severity, msg.chunk_seq - 1, "")
        pending = (text_id, pending[1], msg.chunk_seq, pending[3] + text)
        if ended:
            self._chunks = None
            self._emit_text(pending[1], pending[3], now)
        else:
            self._chunks = pending

    def _emit_text(self, severity: int, text: str, now: float) -> None:
        st = StatusText(severity, text)
        self._texts.append((now, st))
        self._events.append(st)

    def _discovered(self, hb: Message, now: float) -> None:
        src = hb.get_srcSystem()
        self.target_component = hb.get_srcComponent()
        name = AUTOPILOTS.get(hb.autopilot, f"autopilot {hb.autopilot}")
        self.telemetry = replace(
            self.telemetry, system_id=src, autopilot=name, autopilot_id=hb.autopilot
        )
        self._events.append(VehicleFound(src, name, hb.type))
        if self.request_streams:
            for msg_id, hz in STREAMS_HZ.items():
                self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz, now=now)
            self.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION, now=now)
        names = (
            ("NAV_DLL_ACT", "COM_DL_LOSS_T")
            if hb.autopilot == mav.MAV_AUTOPILOT_PX4
            else ("FS_GCS_ENABLE",)
        )
        for pname in names:
            self._send(
                self.m.param_request_read_encode(src, self.target_component, pname.encode(), -1)
            )

    # ------------------------------------------------------------------ commands
    def command(
        self,
        command: int,
        *params: float,
        now: float | None = None,
        use_int: bool = False,
        frame: int = mav.MAV_FRAME_GLOBAL_INT,
        then: list[tuple[int, tuple[float, ...]]] | None = None,
        urgent: bool = False,
    ) -> int:
        """Queue ``command`` with up to seven params; returns its token (in its CommandResult).

        ``then``: commands sent, in order, only after this one is ACCEPTED (arm, then take off).
        ``urgent``: send now even if a command with the same id is in flight (emergency).
        An identical command already waiting for its turn is not queued again; its token
        is returned instead.
        """
        now = self._now if now is None else now
        padded = tuple(float(p) for p in params) + (0.0,) * (7 - len(params))
        cmd = self._make(command, padded, use_int, frame)
        cmd.then = [
            self._make(c, tuple(p) + (0.0,) * (7 - len(p)), False, frame) for c, p in then or ()
        ]
        if urgent:
            self._inflight.pop(command, None)
            self._waiting.pop(command, None)
        busy = self._inflight.get(command)
        if busy is not None:
            for other in (busy, *self._waiting[command]):
                if other.params == padded and not other.then and not cmd.then:
                    return other.token
            self._waiting[command].append(cmd)
            return cmd.token
        self._start(cmd, now)
        return cmd.token

    def _make(self, command: int, params: tuple[float, ...], use_int: bool, frame: int) -> _Command:
        self._token += 1
        return _Command(self._token, command, params, use_int, frame)

    def _start(self, cmd: _Command, now: float) -> None:
        self._inflight[cmd.command] = cmd
        self._transmit(cmd, now)

    def _transmit(self, cmd: _Command, now: float) -> None:
        ts, tc = self.telemetry.system_id or (self.target_system or 1), self.target_component
        p = cmd.params
        if cmd.use_int:
            msg = self.m.command_int_encode(
                ts,
                tc,
                cmd.frame,
                cmd.command,
                0,
                0,
                p[0],
                p[1],
                p[2],
                p[3],
                int(p[4]),
                int(p[5]),
                p[6],
            )
        else:
            msg = self.m.command_long_encode(ts, tc, cmd.command, min(cmd.attempts, 255), *p)
        cmd.attempts += 1
        cmd.sent_t = now
        self.commands_sent += 1
        self._send(msg)

    def _finish(self, cmd: _Command, result: str, now: float, reason: str | None = None) -> None:
        self._inflight.pop(cmd.command, None)
        self._events.append(CommandResult(cmd.token, command_name(cmd.command), result, reason))
        if result == "ACCEPTED" and cmd.then:
            nxt, rest = cmd.then[0], cmd.then[1:]
            nxt.then = rest
            if nxt.command in self._inflight:
                self._waiting[nxt.command].appendleft(nxt)
            else:
                self._start(nxt, now)
        elif cmd.then:
            cause = CommandResult(cmd.token, command_name(cmd.command), result, reason)
            for c in cmd.then:
                self._events.append(
                    CommandResult(
                        c.token,
                        command_name(c.command),
                        "NOT_SENT",
                        f"{command_name(cmd.command)} was not accepted",
                        cause,
                    )
                )
        queue = self._waiting.get(cmd.command)
        if queue and cmd.command not in self._inflight:
            self._start(queue.popleft(), now)

    def _on_ack(self, msg: Message, now: float) -> None:
        cmd = self._inflight.get(msg.command)
        if cmd is None:
            return  # a late duplicate ACK (retransmission answered twice): already settled
        result = _RESULTS.get(msg.result, str(msg.result))
        if msg.result == mav.MAV_RESULT_IN_PROGRESS:
            cmd.progress_t = now
            self._events.append(
                CommandProgress(cmd.token, command_name(cmd.command), int(msg.progress))
            )
            return
        reason = None
        if msg.result != mav.MAV_RESULT_ACCEPTED:
            # The explanation PX4/ArduPilot send as STATUSTEXT just before the ACK.
            recent = [st for t, st in self._texts if now - t <= 1.0 and t >= cmd.sent_t - 0.05]
            reason = recent[-1].text if recent else None
        self._finish(cmd, result, now, reason)

    def _check_commands(self, now: float) -> None:
        for cmd in list(self._inflight.values()):
            if cmd.progress_t is not None:
                if now - cmd.progress_t > 3.0 * self.command_timeout_s:
                    self._finish(cmd, "NO_ANSWER", now, "progress stopped")
                continue
            if now - cmd.sent_t < self.command_timeout_s:
                continue
            if cmd.attempts > self.retries:
                self._finish(cmd, "NO_ANSWER", now)
            else:
                self._transmit(cmd, now)

    def pending_commands(self) -> int:
        return len(self._inflight) + sum(len(q) for q in self._waiting.values())

    # ------------------------------------------------------------------ high-level commands
    def set_mode(self, name: str, now: float | None = None) -> int:
        """DO_SET_MODE to ``name`` (``"AUTO.LOITER"``, ``"GUIDED"``…)."""
        ap = self.telemetry.autopilot_id or mav.MAV_AUTOPILOT_PX4
        cm = custom_mode(ap, name)
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if ap == mav.MAV_AUTOPILOT_PX4:
            return self.command(
                mav.MAV_CMD_DO_SET_MODE, base, (cm >> 16) & 0xFF, (cm >> 24) & 0xFF, now=now
            )
        return self.command(mav.MAV_CMD_DO_SET_MODE, base, cm, now=now)

    def intent(self, intent: str, now: float | None = None) -> int:
        """Change to the mode that does ``intent`` (hold, rtl, land, mission, offboard)."""
        ap = self.telemetry.autopilot_id or mav.MAV_AUTOPILOT_PX4
        return self.set_mode(intent_mode(ap, intent), now)

    def arm_and_takeoff(self, rel_alt_m: float, now: float | None = None) -> int:
        """Arm, then NAV_TAKEOFF to ``rel_alt_m`` above home (sent only once armed).

        The arm is sent even when telemetry says armed: that flag is up to a heartbeat old, and
        a PX4 that has just auto-disarmed after landing denies a bare take-off. Arming an armed
        vehicle is accepted by PX4 and ArduPilot alike, so it costs one round trip.
        """
        home = self.telemetry.home
        alt = (home[2] + rel_alt_m) if home else math.nan
        Step = tuple[int, tuple[float, ...]]
        takeoff: Step = (
            mav.MAV_CMD_NAV_TAKEOFF,
            (-1.0, 0.0, 0.0, math.nan, math.nan, math.nan, alt),
        )
        arm: Step = (mav.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,))
        if self.telemetry.autopilot_id == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
            # ArduCopter takes off only in GUIDED (ArduCopter/mode_guided.cpp), with the
            # altitude relative to home in param7.
            takeoff = (takeoff[0], (0.0, 0.0, 0.0, math.nan, 0.0, 0.0, rel_alt_m))
            guided = float(custom_mode(mav.MAV_AUTOPILOT_ARDUPILOTMEGA, "GUIDED"))
            base = float(mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
            self.command(mav.MAV_CMD_DO_SET_MODE, base, guided, now=now, then=[arm, takeoff])
            return self._token
        self.command(arm[0], *arm[1], now=now, then=[takeoff])
        return self._token  # the take-off's token

    def goto(
        self,
        lat: float,
        lon: float,
        alt_amsl: float,
        heading_deg: float = math.nan,
        now: float | None = None,
    ) -> int:
        """DO_REPOSITION (COMMAND_INT, global): fly there and hold, the autopilot's own goto."""
        return self.command(
            mav.MAV_CMD_DO_REPOSITION,
            -1.0,
            float(mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE),
            0.0,
            heading_deg,
            round(lat * 1e7),
            round(lon * 1e7),
            alt_amsl,
            now=now,
            use_int=True,
            frame=mav.MAV_FRAME_GLOBAL,
        )

    def kill(self, now: float | None = None) -> int:
        """Motors off now (force disarm), ahead of anything queued."""
        self.stop_setpoints(now)
        return self.command(
            mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, float(FORCE_DISARM), now=now, urgent=True
        )

    # ------------------------------------------------------------------ setpoints
    def set_velocity(
        self, vn: float, ve: float, vd: float, yaw_rate: float, now: float | None = None
    ) -> None:
        """Stream a local-NED velocity (m/s) and yaw rate (rad/s, clockwise) until released."""
        now = self._now if now is None else now
        self._setpoint = ("vel", (vn, ve, vd, yaw_rate))
        self._zero_burst = 0
        if self._next_sp > now + self.setpoint_period_s:
            self._next_sp = now
        self._stream(now)

    def set_position(
        self,
        n: float,
        e: float,
        d: float,
        heading: float,
        yaw_rate: float | None = None,
        now: float | None = None,
    ) -> None:
        """Stream a local-NED position target (and heading, or a yaw rate) until released."""
        now = self._now if now is None else now
        self._setpoint = ("pos", (n, e, d, heading, math.nan if yaw_rate is None else yaw_rate))
        self._zero_burst = 0
        self._stream(now)

    def stop_setpoints(self, now: float | None = None) -> None:
        """Stop streaming; a velocity stream ends with zero velocity (sent three times)."""
        if self._setpoint is not None and self._setpoint[0] == "vel":
            self._setpoint = ("vel", (0.0, 0.0, 0.0, 0.0))
            self._zero_burst = 3
            self._stream(self._now if now is None else now)
        else:
            self._setpoint = None

    @property
    def streaming(self) -> str | None:
        return self._setpoint[0] if self._setpoint else None

    def _stream(self, now: float) -> None:
        if self._setpoint is None or self.telemetry.system_id == 0:
            return
        kind, v = self._setpoint
        ts, tc = self.telemetry.system_id, self.target_component
        ms = int(now * 1000) & 0xFFFFFFFF
        if kind == "vel":
            mask = (
                mav.POSITION_TARGET_TYPEMASK_X_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_Y_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_Z_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_AX_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE
            )
            msg = self.m.set_position_target_local_ned_encode(
                ms,
                ts,
                tc,
                mav.MAV_FRAME_LOCAL_NED,
                mask,
                0.0,
                0.0,
                0.0,
                v[0],
                v[1],
                v[2],
                0.0,
                0.0,
                0.0,
                0.0,
                v[3],
            )
        else:
            mask = (
                mav.POSITION_TARGET_TYPEMASK_VX_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_VY_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_VZ_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_AX_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
                | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE
            )
            rate = v[4]
            if math.isnan(rate):
                mask |= mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
                rate = 0.0
            else:
                mask |= mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE
            msg = self.m.set_position_target_local_ned_encode(
                ms,
                ts,
                tc,
                mav.MAV_FRAME_LOCAL_NED,
                mask,
                v[0],
                v[1],
                v[2],
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                v[3],
                rate,
            )
        self._send(msg)
        self._next_sp = now + self.setpoint_period_s
        if self._zero_burst:
            self._zero_burst -= 1
            if self._zero_burst == 0:
                self._setpoint = None

    # ------------------------------------------------------------------ mission upload
    def upload_mission(
        self,
        waypoints: list[tuple[float, float, float]],
        now: float | None = None,
        *,
        takeoff_alt_m: float | None = None,
        rtl: bool = False,
    ) -> None:
        """Upload waypoints (lat°, lon°, alt m above home) as a mission; MissionResult follows."""
        now = self._now if now is None else now
        ts, tc = self.telemetry.system_id, self.target_component
        items: list[Message] = []
        rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        if takeoff_alt_m is not None:
            items.append(
                self.m.mission_item_int_encode(
                    ts,
                    tc,
                    0,
                    rel,
                    mav.MAV_CMD_NAV_TAKEOFF,
                    0,
                    1,
                    0,
                    0,
                    0,
                    math.nan,
                    0,
                    0,
                    takeoff_alt_m,
                )
            )
        for lat, lon, alt in waypoints:
            items.append(
                self.m.mission_item_int_encode(
                    ts,
                    tc,
                    len(items),
                    rel,
                    mav.MAV_CMD_NAV_WAYPOINT,
                    0,
                    1,
                    0.0,
                    1.0,
                    0.0,
                    math.nan,
                    round(lat * 1e7),
                    round(lon * 1e7),
                    alt,
                )
            )
        if rtl:
            items.append(
                self.m.mission_item_int_encode(
                    ts,
                    tc,
                    len(items),
                    rel,
                    mav.MAV_CMD_NAV_RETURN_TO_LAUNCH,
                    0,
                    1,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            )
        self._upload = _Upload(items, now, now)
        self._send(self.m.mission_count_encode(ts, tc, len(items)))

    def _on_mission_request(self, msg: Message, now: float) -> None:
        up = self._upload
        if up is None:
            return
        if not 0 <= msg.seq < len(up.items):
            self._upload = None
            self._events.append(MissionResult(False, len(up.items), f"bad item request {msg.seq}"))
            return
        up.last_t, up.tries = now, 0
        self._send(up.items[msg.seq])

    def _on_mission_ack(self, msg: Message) -> None:
        up = self._upload
        if up is None:
            return
        self._upload = None
        name = _MISSION_RESULTS.get(msg.type, f"result {msg.type}")
        ok = msg.type == mav.MAV_MISSION_ACCEPTED
        recent = [st.text for t, st in self._texts if self._now - t <= 1.0]
        detail = name if ok or not recent else f"{name}: {recent[-1]}"
        self._events.append(MissionResult(ok, len(up.items), detail))

    def _check_upload(self, now: float) -> None:
        up = self._upload
        if up is None or now - up.last_t < 1.5:
            return
        if up.tries >= 3:
            self._upload = None
            self._events.append(MissionResult(False, len(up.items), "no answer from the vehicle"))
            return
        up.tries += 1
        up.last_t = now
        ts, tc = self.telemetry.system_id, self.target_component
        self._send(self.m.mission_count_encode(ts, tc, len(up.items)))

    # ------------------------------------------------------------------ time
    def tick(self, now: float) -> None:
        """Heartbeat, retries, setpoint stream, upload timeouts, link watchdog."""
        self._now = now
        if self.codec.signed:
            self.codec.keep_up(signing_timestamp(self.signing_clock()))
        if now >= self._next_hb:
            self._next_hb = now + HEARTBEAT_PERIOD_S
            self._send(
                self.m.heartbeat_encode(
                    mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE
                )
            )
        self._check_commands(now)
        self._check_upload(now)
        if self._setpoint is not None and now >= self._next_sp:
            self._stream(now)
        hb = self.telemetry.last_heartbeat_t
        if self.link_ok and hb is not None and now - hb > self.link_timeout_s:
            self.link_ok = False
            self._events.append(LinkLost(now - hb, self.failsafe_text()))

    def failsafe_text(self) -> str:
        """What the autopilot does on its own when it stops hearing us, in words."""
        t = self.telemetry
        if t.autopilot_id == mav.MAV_AUTOPILOT_PX4:
            act = self.params.get("NAV_DLL_ACT")
            wait = self.params.get("COM_DL_LOSS_T", 10.0)
            what = {
                0: "nothing (data-link failsafe disabled)",
                1: "hold",
                2: "return to launch",
                3: "land",
                5: "terminate",
                6: "lock down",
            }
            if act is None:
                return f"PX4's data-link-loss failsafe (NAV_DLL_ACT) acts after {wait:.0f} s"
            return (
                f"PX4's data-link-loss failsafe will {what.get(int(act), 'act')} after {wait:.0f} s"
            )
        if t.autopilot_id == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
            fs = self.params.get("FS_GCS_ENABLE")
            if fs == 0:
                return "ArduPilot's GCS failsafe is disabled (FS_GCS_ENABLE 0)"
            return "ArduPilot's GCS failsafe (FS_GCS_ENABLE) acts after FS_GCS_TIMEOUT"
        return "the autopilot's own failsafe acts"
