"""``SimAutopilot``: a sans-I/O PX4-like autopilot around the project's physics and battery.

It presents itself on the wire as PX4 SITL does (PX4-Autopilot ``src/modules/mavlink``,
``src/modules/commander``), so ground stations and MAVSDK treat it as a PX4 quadrotor:

* HEARTBEAT 1 Hz as ``MAV_TYPE_QUADROTOR`` / ``MAV_AUTOPILOT_PX4`` with PX4 custom modes
  (``drone.mavlink.modes``), ``MAV_MODE_FLAG_SAFETY_ARMED`` when armed; SYS_STATUS with gyro,
  accelerometer, magnetometer, barometer, GPS and pre-arm health bits set, so MAVSDK's
  ``health_all_ok`` holds; EXTENDED_SYS_STATE (landed state), GPS_RAW_INT (3D fix),
  GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ATTITUDE, BATTERY_STATUS, HOME_POSITION,
  MISSION_CURRENT; rates changed by ``MAV_CMD_SET_MESSAGE_INTERVAL`` per link;
* commands (COMMAND_LONG and COMMAND_INT) with COMMAND_ACK, one handler each in a table
  (``_command_table``): arm/disarm (disarm in the air is DENIED unless forced with 21196),
  take-off (param7 AMSL; NaN: MIS_TAKEOFF_ALT, 2.5 m, above the vehicle), land, RTL,
  DO_SET_MODE, DO_REPOSITION (PX4 "goto": fly there and hold), MISSION_START, DO_CHANGE_SPEED,
  DO_FLIGHTTERMINATION, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES;
  anything else UNSUPPORTED. A retransmission (same command, higher ``confirmation``) of a
  command already executed is answered with the same result and not executed again;
* altitude frames as PX4's: GLOBAL_POSITION_INT ``alt`` AMSL and ``relative_alt`` above home
  (mm), GPS_RAW_INT and HOME_POSITION AMSL (mm), LOCAL_POSITION_NED and HOME_POSITION's
  x/y/z from the local origin (where the vehicle started, PX4's estimator origin; home moves to
  wherever it arms); a take-off, reposition or mission item above the room's ceiling, or above
  GF_MAX_VER_DIST over home when that geofence is set, is refused with the reason in STATUSTEXT
  (it would stop at the ceiling and never arrive);
* the mission protocol (upload and download, MISSION_ITEM_INT, MISSION_ACK, CLEAR_ALL,
  SET_CURRENT, MISSION_ITEM_REACHED) with NAV_WAYPOINT, NAV_TAKEOFF, NAV_LAND and
  NAV_RETURN_TO_LAUNCH items;
* offboard: SET_POSITION_TARGET_LOCAL_NED (position or velocity by ``type_mask``); OFFBOARD
  is entered on request once setpoints stream; setpoints stopping for COM_OF_LOSS_T (1 s) →
  AUTO.LOITER (PX4's default COM_OBL_RC_ACT);
* failsafes: no GCS heartbeat for COM_DL_LOSS_T (10 s) while flying → the action of
  NAV_DLL_ACT (here 2, Return — PX4 ships it disabled, 0, but PX4's documentation recommends
  enabling it for missions; set the parameter to 0 to disable); battery below BAT_CRIT_THR
  (7 %) → RTL, below BAT_EMERGEN_THR (5 %) → land; each announced in STATUSTEXT as PX4 does;
* after landing it disarms after COM_DISARM_LAND (2 s); armed on the ground without a take-off
  it disarms after COM_DISARM_PRFLT (10 s).

The position controller is PX4's cascade in miniature: position P (MPC_XY_P 0.95) → velocity
(≤ MPC_XY_CRUISE 5 m/s, ≤ MPC_Z_VEL_MAX_UP 3 m/s, ≤ MPC_Z_VEL_MAX_DN 1 m/s) → velocity P with
drag feed-forward → tilt (≤ 35°) → the physics' attitude loop. Landing descends at
MPC_LAND_SPEED 0.7 m/s.

MAVLink 2 signing (``signing_key``): every link shares one signing state, unsigned and badly
signed frames are refused and counted, and a link that sent only refused frames is told once
(STATUSTEXT "Refused: MAVLink 2 signing required").

Sans-I/O: ``connect(cid)``, ``receive(cid, data)``, ``step(dt)``, ``drain(cid) -> bytes``; the
clock is the autopilot's own ``time`` (advanced by ``step``); only the signing timestamps read
``signing_clock`` (Unix time). ``drone.mavlink.simserver`` pumps
it on sockets; ``drone.mavlink.lockstep`` in memory.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drone.ardrone.navdata import CtrlState
from drone.mavlink.codec import Codec, Message, mav, signing_state, signing_timestamp
from drone.mavlink.geo import Origin, enu_to_ned, yaw_enu_to_ned, yaw_ned_to_enu
from drone.mavlink.modes import px4_custom_mode, px4_mode_name
from drone.sim.battery import Battery
from drone.sim.drone import Truth
from drone.sim.errors import SimConfigError
from drone.sim.physics import Body, FlightParams, Physics, as_box

RESULT_ACCEPTED: int = int(mav.MAV_RESULT_ACCEPTED)  # typed copies (pymavlink is untyped)
RESULT_DENIED: int = int(mav.MAV_RESULT_DENIED)
RESULT_UNSUPPORTED: int = int(mav.MAV_RESULT_UNSUPPORTED)
FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (PX4 commander)
REFUSED_UNSIGNED = b"Refused: MAVLink 2 signing required"  # STATUSTEXT, <= 50 bytes
DEFAULT_ORIGIN = Origin(47.397742, 8.545594, 488.0)  # PX4 SITL's default home (Zurich)
SENSORS = (
    mav.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mav.MAV_SYS_STATUS_SENSOR_GPS
    | mav.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mav.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mav.MAV_SYS_STATUS_SENSOR_BATTERY
    | mav.MAV_SYS_STATUS_PREARM_CHECK
)
# Default stream rates (Hz) of PX4's "Normal" MAVLink mode (mavlink_main.cpp configure_streams).
DEFAULT_RATES_HZ = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0,
    "GPS_RAW_INT": 1.0,
    "GLOBAL_POSITION_INT": 5.0,
    "LOCAL_POSITION_NED": 5.0,
    "ATTITUDE": 15.0,
    "BATTERY_STATUS": 0.5,
    "HOME_POSITION": 0.5,
    "MISSION_CURRENT": 0.5,
}
_FLOWN_TO = (mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LOITER_UNLIM)
_MSG_IDS = {name: getattr(mav, f"MAVLINK_MSG_ID_{name}") for name in DEFAULT_RATES_HZ}
_MSG_NAMES = {v: k for k, v in _MSG_IDS.items()}
# MAVLink 2 (mavlink.io "Packet Serialization"): frames up to 280 bytes; several per datagram.


@dataclass
class AutopilotParams:
    """Parameters with PX4's names and defaults (except NAV_DLL_ACT, see module docstring)."""

    MIS_TAKEOFF_ALT: float = 2.5
    GF_MAX_VER_DIST: float = 0.0  # geofence: highest above home, m (0: only the room's ceiling)
    RTL_RETURN_ALT: float = 10.0
    RTL_DESCEND_ALT: float = 5.0
    NAV_DLL_ACT: float = 2.0  # 0 disabled, 1 hold, 2 return, 3 land
    COM_DL_LOSS_T: float = 10.0
    COM_OF_LOSS_T: float = 1.0
    COM_DISARM_LAND: float = 2.0
    COM_DISARM_PRFLT: float = 10.0
    BAT_LOW_THR: float = 15.0
    BAT_CRIT_THR: float = 7.0
    BAT_EMERGEN_THR: float = 5.0
    MPC_XY_CRUISE: float = 5.0
    MPC_Z_VEL_MAX_UP: float = 3.0
    MPC_Z_VEL_MAX_DN: float = 1.0
    MPC_LAND_SPEED: float = 0.7
    NAV_ACC_RAD: float = 1.0

    def names(self) -> list[str]:
        return list(self.__dataclass_fields__)


@dataclass
class _Link:
    """One client link: its codec, outgoing bytes, stream rates and next send times."""

    codec: Codec
    out: bytearray = field(default_factory=bytearray)
    rates_hz: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_RATES_HZ))
    next_t: dict[str, float] = field(default_factory=dict)
    mission_up: tuple[int, int, list[Any]] | None = None  # (sysid, count, items so far)
    told_unsigned: bool = False  # "signing required" already sent on this link


@dataclass(frozen=True)
class MissionItem:
    """One mission item as the autopilot keeps it (map frame target)."""

    seq: int
    command: int
    x: float
    y: float
    z: float
    raw: Any


class SimAutopilot:
    """See the module docstring.

    Args:
        world: a ``drone.sim.world.World`` (bounds, start, gps_origin); None: an open field.
        start: ``(x, y, yaw_rad)`` on the ground (default the world's start).
        system_id: MAVLink system id (PX4 SITL: 1).
        battery_pct: initial charge.
        signing_key: require MAVLink 2 signing on every link (32 bytes). All links share one
            signing state (``drone.mavlink.codec.signing_state``): a frame replayed on a new
            link is as old as on its own.
        signing_clock: Unix time, for the signing timestamps only (kept at least at it).
        refuse_all: test double of a vehicle that denies every command (bad-input tests).
        silent: never answer commands (a vehicle that only streams telemetry).
    """

    def __init__(
        self,
        world: Any | None = None,
        *,
        start: tuple[float, float, float] | None = None,
        system_id: int = 1,
        battery_pct: float = 100.0,
        params: AutopilotParams | None = None,
        signing_key: bytes | None = None,
        signing_clock: Callable[[], float] = time.time,
        refuse_all: bool = False,
        silent: bool = False,
    ) -> None:
        box = as_box(getattr(world, "bounds", None) or (-200.0, 200.0, -200.0, 200.0, 0.0, 60.0))
        if start is None:
            ws = getattr(world, "start", None)
            start = (float(ws.x), float(ws.y), float(ws.yaw_rad)) if ws else (0.0, 0.0, 0.0)
        x, y, yaw = start
        if not (box[0] <= x <= box[1] and box[2] <= y <= box[3]):
            raise SimConfigError(f"start {start} lies outside the bounds {box}")
        fp = FlightParams(
            euler_angle_max_rad=math.radians(35.0),  # MPC_TILTMAX_AIR 45°, kept below it
            control_vz_max_m_s=3.0,
            control_yaw_rad_s=math.radians(90.0),  # MPC_YAWRAUTO_MAX 45°/s… MC_YAWRATE_MAX
            altitude_max_m=box[5] - box[4],
            radius_m=0.25,
        )
        self.physics = Physics(
            bounds=box,
            params=fp,
            battery=Battery(pct=battery_pct, flight_time_s=1200.0),  # a 20-minute quad
            body=Body(x=x, y=y, z=box[4], yaw_rad=yaw),
        )
        go = getattr(world, "gps_origin", None)
        self.origin = Origin(go.lat_deg, go.lon_deg, go.alt_m) if go else DEFAULT_ORIGIN
        self.system_id = system_id
        self.component_id = mav.MAV_COMP_ID_AUTOPILOT1
        self.params = params or AutopilotParams()
        self.signing_key = signing_key
        self.signing_clock = signing_clock
        self._signing: Any = None
        if signing_key is not None:
            self._signing = signing_state(signing_key, timestamp=signing_timestamp(signing_clock()))
        self.refuse_all = refuse_all
        self.silent = silent
        self.time = 0.0
        self.home = (x, y, box[4], yaw)
        # PX4's local NED origin is where its estimator got its first position (here the start
        # on the floor) and stays there; home moves to wherever the vehicle arms.
        self.local_origin = (x, y, box[4])
        self.armed = False
        self.mode = "AUTO.LOITER"
        self.landed_state = mav.MAV_LANDED_STATE_ON_GROUND
        self.links: dict[object, _Link] = {}
        self.mission: list[MissionItem] = []
        self.mission_current = 0
        self.commands_executed: list[int] = []  # every command acted upon, in order (tests)
        self.statustexts: list[str] = []
        self._target: tuple[float, float, float, float] = (x, y, box[4], yaw)  # hold point
        self._vel_sp: tuple[float, float, float] | None = None  # offboard velocity (map)
        self._offboard_t = -math.inf  # last offboard setpoint
        self._gcs_t: float | None = None  # last GCS heartbeat (None: no GCS yet)
        self._dl_lost = False
        self._bat_stage = 0  # 0 ok, 1 low warned, 2 critical (RTL), 3 emergency (land)
        self._landed_since: float | None = None
        self._armed_since = 0.0
        self._took_off = False
        self._rtl_phase = ""
        self._speed = self.params.MPC_XY_CRUISE
        self._recent: dict[tuple[int, int, int], tuple[float, int, int]] = {}  # dedupe retries
        self._rtl_z = 0.0
        self._link_down_until = -math.inf
        self._commands = self._command_table()

    # ------------------------------------------------------------------ links
    def connect(self, cid: object) -> None:
        """A new client link (TCP connection, UDP peer, in-memory end)."""
        self.links[cid] = _Link(Codec(self.system_id, self.component_id, signing=self._signing))

    def disconnect(self, cid: object) -> None:
        self.links.pop(cid, None)

    @property
    def link_down(self) -> bool:
        """True while an injected ``link_loss`` fault drops every byte both ways."""
        return self.time < self._link_down_until

    def drain(self, cid: object) -> bytes:
        """Bytes due to ``cid`` (empty when nothing is, or while the link is down)."""
        link = self.links.get(cid)
        if link is None or not link.out:
            return b""
        data = bytes(link.out)
        link.out.clear()
        return b"" if self.link_down else data

    def accepted(self, cid: object) -> int:
        """Frames accepted from ``cid`` so far (0 for an unknown link)."""
        link = self.links.get(cid)
        return link.codec.accepted if link is not None else 0

    def rejected(self) -> dict[str, int]:
        """Frames refused on all links, by reason (garbage, bad_crc, mavlink1, bad_signature)."""
        total: dict[str, int] = {}
        for link in self.links.values():
            for k, v in link.codec.rejected.items():
                total[k] = total.get(k, 0) + v
        return total

    def _send(self, cid: object, msg: Message) -> None:
        link = self.links.get(cid)
        if link is not None:
            link.out += link.codec.encode(msg)

    def _broadcast(self, msg: Message) -> None:
        for cid in self.links:
            self._send(cid, msg)

    def statustext(self, severity: int, text: str) -> None:
        """Announce ``text`` to every link (STATUSTEXT, ≤ 50 characters as one chunk)."""
        self.statustexts.append(text)
        m = self.links and next(iter(self.links.values())).codec.mav
        if not m:
            return
        self._broadcast(m.statustext_encode(severity, text.encode()[:50]))

    # ------------------------------------------------------------------ input
    def receive(self, cid: object, data: bytes) -> None:
        """Bytes from ``cid``; unknown links are connected on the fly (UDP peers)."""
        if self.link_down:
            return
        if cid not in self.links:
            self.connect(cid)
        link = self.links[cid]
        for msg in link.codec.feed(data):
            self._handle(cid, msg)
        if (
            link.codec.signed
            and not link.told_unsigned
            and link.codec.accepted == 0
            and link.codec.rejected["bad_signature"]
        ):
            # Say why nothing this link sends is obeyed: a ground station without the key reads
            # signed frames (MAVLink "Message Signing"), so it shows this line.
            link.told_unsigned = True
            m = link.codec.mav
            self._send(cid, m.statustext_encode(mav.MAV_SEVERITY_ERROR, REFUSED_UNSIGNED))

    def _handle(self, cid: object, msg: Message) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == mav.MAV_TYPE_GCS:
                self._gcs_t = self.time
                if self._dl_lost:
                    self._dl_lost = False
                    self.statustext(mav.MAV_SEVERITY_INFO, "Data link regained")
            return
        target = getattr(msg, "target_system", None)
        if target not in (None, 0, self.system_id):
            return  # for another vehicle on the same link
        handler: Callable[[object, Message], None] | None = {
            "COMMAND_LONG": self._on_command,
            "COMMAND_INT": self._on_command,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_setpoint,
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_CLEAR_ALL": self._on_mission_clear,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "PARAM_REQUEST_LIST": self._on_param_list,
            "PARAM_REQUEST_READ": self._on_param_read,
            "PARAM_SET": self._on_param_set,
            "TIMESYNC": self._on_timesync,
        }.get(kind)
        if handler is not None:
            handler(cid, msg)

    # ------------------------------------------------------------------ commands
    def _ack(self, cid: object, msg: Message, result: int) -> None:
        m = self.links[cid].codec.mav
        ack = m.command_ack_encode(
            msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )
        self._send(cid, ack)

    def _on_command(self, cid: object, msg: Message) -> None:
        if self.silent:
            return
        key = (msg.get_srcSystem(), msg.get_srcComponent(), msg.command)
        confirmation = getattr(msg, "confirmation", 0)
        prev = self._recent.get(key)
        if prev is not None and confirmation > prev[1] and self.time - prev[0] < 3.0:
            # A retransmission of a command we already acted on (its ACK was lost): answer the
            # same, do not act twice (MAVLink "Command Protocol": confirmation field).
            self._recent[key] = (self.time, confirmation, prev[2])
            self._ack(cid, msg, prev[2])
            return
        if self.refuse_all:
            result = mav.MAV_RESULT_DENIED
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Command denied: vehicle locked")
        else:
            try:
                result = self._execute(msg)
            except (ValueError, OverflowError):  # NaN/inf where an integer is meant
                self.statustext(mav.MAV_SEVERITY_CRITICAL, "Command rejected: invalid parameter")
                result = RESULT_DENIED
            if result in (mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_IN_PROGRESS):
                self.commands_executed.append(msg.command)
        self._recent[key] = (self.time, confirmation, result)
        self._ack(cid, msg, result)
        if msg.command == mav.MAV_CMD_REQUEST_MESSAGE and result == mav.MAV_RESULT_ACCEPTED:
            self._send_requested(cid, int(msg.param1))
        if msg.command == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._send_requested(cid, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)

    def _global_target(self, msg: Message) -> tuple[float, float, float] | None:
        """DO_REPOSITION's target in the map frame (COMMAND_INT degE7 or COMMAND_LONG degrees)."""
        if msg.get_type() == "COMMAND_INT":
            lat, lon, alt = msg.x / 1e7, msg.y / 1e7, float(msg.z)
            relative = msg.frame in (
                mav.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            )
        else:
            lat, lon, alt = float(msg.param5), float(msg.param6), float(msg.param7)
            relative = False
        if not (math.isfinite(lat) and math.isfinite(lon)) or (lat == 0 and lon == 0):
            return None
        b = self.physics.body
        if not math.isfinite(alt):
            z = b.z
        elif relative:
            z = self.home[2] + alt
        else:
            z = alt - self.origin.alt_m
        x, y, _ = self.origin.to_map(lat, lon, self.origin.alt_m)
        return x, y, z

    def _execute(self, msg: Message) -> int:
        """Act on a command (COMMAND_LONG or COMMAND_INT): its handler in :attr:`_commands`,
        UNSUPPORTED for any other."""
        handler = self._commands.get(int(msg.command))
        return handler(msg) if handler is not None else RESULT_UNSUPPORTED

    def _command_table(self) -> dict[int, Callable[[Message], int]]:
        """Command id → handler, by PX4 service: commander (arming, modes, take-off, landing,
        return, termination), navigator (reposition, mission, speed), mavlink (streams)."""
        return {
            mav.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm_disarm,
            mav.MAV_CMD_NAV_TAKEOFF: self._cmd_takeoff,
            mav.MAV_CMD_NAV_LAND: self._cmd_land,
            mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._cmd_return,
            mav.MAV_CMD_DO_SET_MODE: self._cmd_set_mode,
            mav.MAV_CMD_DO_FLIGHTTERMINATION: self._cmd_terminate,
            mav.MAV_CMD_DO_REPOSITION: self._cmd_reposition,
            mav.MAV_CMD_MISSION_START: self._cmd_mission_start,
            mav.MAV_CMD_DO_CHANGE_SPEED: self._cmd_change_speed,
            mav.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_message_interval,
            mav.MAV_CMD_REQUEST_MESSAGE: self._cmd_request_message,
            mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._cmd_request_message,
        }

    # commander
    def _cmd_arm_disarm(self, msg: Message) -> int:
        if msg.param1 >= 0.5:
            return self._arm()
        if self._in_air and int(msg.param2) != FORCE_MAGIC:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
            return RESULT_DENIED
        self._disarm("commanded")
        return RESULT_ACCEPTED

    def _cmd_takeoff(self, msg: Message) -> int:
        """NAV_TAKEOFF as PX4's navigator reads it (``takeoff.cpp`` set_takeoff_position):
        param7 is the altitude AMSL; NaN means MIS_TAKEOFF_ALT above where the vehicle is; a
        target below the vehicle keeps it where it is ("Already higher than takeoff altitude").
        One leniency: a finite param7 at or below the ground (0, as scripts written for
        ArduPilot's relative param7 send) is read as NaN, not as "stay on the ground"."""
        if not self.armed:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Takeoff denied: disarmed")
            return RESULT_DENIED
        alt = float(msg.param7) if msg.get_type() == "COMMAND_LONG" else float(msg.z)
        if math.isfinite(alt) and alt > self.origin.alt_m + self.home[2]:
            return self._takeoff(alt - self.origin.alt_m)
        return self._takeoff(None)

    def _cmd_land(self, msg: Message) -> int:
        if not self._in_air:
            return RESULT_DENIED
        self._set_mode("AUTO.LAND")
        return RESULT_ACCEPTED

    def _cmd_return(self, msg: Message) -> int:
        if not self._in_air:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Return denied: landed")
            return RESULT_DENIED
        self._set_mode("AUTO.RTL")
        return RESULT_ACCEPTED

    def _cmd_set_mode(self, msg: Message) -> int:
        if not int(msg.param1) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return RESULT_DENIED
        name = px4_mode_name((int(msg.param2) << 16) | (int(msg.param3) << 24))
        return self._request_mode(name)

    def _cmd_terminate(self, msg: Message) -> int:
        if msg.param1 >= 0.5:
            self.physics.cut_motors()
            self.armed = False
            self.statustext(mav.MAV_SEVERITY_EMERGENCY, "Flight termination active")
        return RESULT_ACCEPTED

    # navigator
    def _cmd_reposition(self, msg: Message) -> int:
        if not self._in_air:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Reposition denied: not flying")
            return RESULT_DENIED
        target = self._global_target(msg)
        if target is None:
            return RESULT_DENIED
        if target[2] <= self.physics.bounds[4]:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Reposition denied: below ground")
            return RESULT_DENIED
        if target[2] > self.ceiling_z + 1e-6:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Reposition is outside geofence")
            return RESULT_DENIED
        yaw_deg = float(msg.param4)
        yaw = yaw_ned_to_enu(math.radians(yaw_deg)) if math.isfinite(yaw_deg) else self._target[3]
        if msg.param1 > 0:
            self._speed = min(float(msg.param1), self.params.MPC_XY_CRUISE)
        self._set_mode("AUTO.LOITER")
        self._target = (*target, yaw)
        return RESULT_ACCEPTED

    def _cmd_mission_start(self, msg: Message) -> int:
        if not self.mission:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Mission rejected: no mission")
            return RESULT_DENIED
        if not self.armed:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Mission denied: disarmed")
            return RESULT_DENIED
        self.mission_current = max(0, min(int(msg.param1), len(self.mission) - 1))
        self._set_mode("AUTO.MISSION")
        return RESULT_ACCEPTED

    def _cmd_change_speed(self, msg: Message) -> int:
        if msg.param2 > 0:
            self._speed = min(float(msg.param2), self.params.MPC_XY_CRUISE)
        return RESULT_ACCEPTED

    # mavlink streams
    def _cmd_message_interval(self, msg: Message) -> int:
        return self._set_interval(msg, int(msg.param1), float(msg.param2))

    def _cmd_request_message(self, msg: Message) -> int:
        known = _MSG_NAMES.keys() | {mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION}
        if msg.command == mav.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) not in known:
            return RESULT_UNSUPPORTED
        return RESULT_ACCEPTED

    def _set_interval(self, msg: Message, msg_id: int, interval_us: float) -> int:
        name = _MSG_NAMES.get(msg_id)
        if not math.isfinite(interval_us):
            return RESULT_DENIED
        if name is None:
            return RESULT_UNSUPPORTED
        for link in self.links.values():
            if interval_us < 0:
                link.rates_hz[name] = 0.0
            elif interval_us == 0:
                link.rates_hz[name] = DEFAULT_RATES_HZ[name]
            else:
                link.rates_hz[name] = min(1e6 / interval_us, 50.0)  # PX4 caps by bandwidth
            link.next_t[name] = self.time
        return RESULT_ACCEPTED

    def _arm(self) -> int:
        if self.armed:
            return RESULT_ACCEPTED
        if self.physics.emergency:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Arming denied: flight terminated")
            return RESULT_DENIED
        if self.physics.battery.pct < self.params.BAT_LOW_THR:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Arming denied: low battery")
            return RESULT_DENIED
        self.armed = True
        self._armed_since = self.time
        self._took_off = False
        b = self.physics.body
        self.home = (b.x, b.y, b.z, b.yaw_rad)
        self.statustext(mav.MAV_SEVERITY_INFO, "Armed by external command")
        return RESULT_ACCEPTED

    def _disarm(self, why: str) -> None:
        if not self.armed:
            return
        self.armed = False
        self.physics.ctrl = CtrlState.LANDED
        self.physics.hover()
        self._vel_sp = None
        self.statustext(mav.MAV_SEVERITY_INFO, f"Disarmed ({why})")

    @property
    def ceiling_z(self) -> float:
        """The highest map z the vehicle may be sent to (see :meth:`_ceiling`)."""
        return self._ceiling()[0]

    def _ceiling(self) -> tuple[float, str]:
        """(map z, "ceiling" or "geofence"): the room's ceiling as the physics keeps it (the
        world's top less the airframe's height, within its altitude limit above the floor),
        lowered to GF_MAX_VER_DIST above home when that geofence is set (PX4: 0 is off)."""
        ph = self.physics
        room = min(ph.bounds[4] + ph.params.altitude_max_m, ph.bounds[5] - ph.params.height_m)
        fence = self.params.GF_MAX_VER_DIST
        if math.isfinite(fence) and fence > 0 and self.home[2] + fence < room:
            return self.home[2] + fence, "geofence"
        return room, "ceiling"

    def _takeoff(self, target_z: float | None) -> int:
        """Take off to map z ``target_z`` (None: MIS_TAKEOFF_ALT above where the vehicle is),
        never lower than it is. A target above :attr:`ceiling_z` is refused with the reason:
        flying there would stop at the ceiling with the take-off never complete."""
        b = self.physics.body
        if not self.physics.battery.can_take_off and not self._in_air:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Takeoff denied: low battery")
            return RESULT_DENIED
        if target_z is None:
            alt = self.params.MIS_TAKEOFF_ALT
            if not math.isfinite(alt):
                return RESULT_DENIED
            target_z = b.z + alt
            self.statustext(mav.MAV_SEVERITY_INFO, f"Using default takeoff altitude: {alt:.1f} m")
        if target_z < b.z:
            target_z = b.z
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Already higher than takeoff altitude")
        ceiling, what = self._ceiling()
        if target_z > ceiling + 1e-6:
            hz = self.home[2]
            self.statustext(
                mav.MAV_SEVERITY_CRITICAL,
                f"Takeoff denied: {target_z - hz:.1f} m above {what} ({ceiling - hz:.1f} m)",
            )
            return RESULT_DENIED
        self._set_mode("AUTO.TAKEOFF")
        self._target = (b.x, b.y, target_z, b.yaw_rad)
        self.physics.ctrl = CtrlState.FLYING
        self._took_off = True
        self.statustext(mav.MAV_SEVERITY_INFO, "Takeoff detected")
        return RESULT_ACCEPTED

    def _request_mode(self, name: str) -> int:
        """DO_SET_MODE: what PX4's commander allows."""
        if name in ("AUTO.LOITER", "POSCTL", "ALTCTL"):
            self._hold_here()
            self._set_mode(name)
        elif name == "AUTO.RTL" or name == "AUTO.LAND":
            if not self._in_air:
                return RESULT_DENIED
            self._set_mode(name)
        elif name == "AUTO.TAKEOFF":
            if not self.armed:
                return RESULT_DENIED
            return self._takeoff(None)
        elif name == "AUTO.MISSION":
            if not self.mission:
                self.statustext(mav.MAV_SEVERITY_CRITICAL, "Mission rejected: no mission")
                return RESULT_DENIED
            self._set_mode(name)
        elif name == "OFFBOARD":
            if self.time - self._offboard_t > self.params.COM_OF_LOSS_T:
                self.statustext(mav.MAV_SEVERITY_CRITICAL, "Switching to Offboard denied")
                return RESULT_DENIED
            self._set_mode(name)
        else:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, f"Mode {name} not supported")
            return RESULT_DENIED
        return RESULT_ACCEPTED

    def _set_mode(self, name: str) -> None:
        if name == "AUTO.RTL":
            self._rtl_phase = "climb"
        if name != "OFFBOARD":
            self._vel_sp = None
        self.mode = name

    def _hold_here(self) -> None:
        b = self.physics.body
        self._target = (b.x, b.y, b.z, b.yaw_rad)

    # ------------------------------------------------------------------ offboard
    def _on_setpoint(self, cid: object, msg: Message) -> None:
        if msg.coordinate_frame not in (mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_OFFSET_NED):
            return
        mask = msg.type_mask
        ox, oy, oz = self.local_origin
        self._offboard_t = self.time
        yaw_ignored = bool(mask & mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE)
        yaw = self._target[3] if yaw_ignored else yaw_ned_to_enu(msg.yaw)
        values = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.yaw)
        if not all(math.isfinite(v) for v in values):
            return  # NaN setpoints are ignored, as PX4 does for fields it cannot use
        if not mask & mav.POSITION_TARGET_TYPEMASK_X_IGNORE:
            # position: local NED from the local origin (PX4's estimator origin)
            self._target = (ox + msg.y, oy + msg.x, oz - msg.z, yaw)
            self._vel_sp = None
        elif not mask & mav.POSITION_TARGET_TYPEMASK_VX_IGNORE:
            self._vel_sp = (msg.vy, msg.vx, -msg.vz)
            self._target = (*self._target[:3], yaw)

    # ------------------------------------------------------------------ mission protocol
    def _on_mission_count(self, cid: object, msg: Message) -> None:
        if msg.mission_type != mav.MAV_MISSION_TYPE_MISSION:
            self._mission_ack(cid, msg, mav.MAV_MISSION_UNSUPPORTED)
            return
        if msg.count == 0:
            self.mission = []
            self._mission_ack(cid, msg, mav.MAV_MISSION_ACCEPTED)
            return
        if msg.count > 500:
            self._mission_ack(cid, msg, mav.MAV_MISSION_NO_SPACE)
            return
        self.links[cid].mission_up = (msg.get_srcSystem(), msg.count, [])
        self._request_item(cid, msg, 0)

    def _request_item(self, cid: object, msg: Message, seq: int) -> None:
        m = self.links[cid].codec.mav
        req = m.mission_request_int_encode(msg.get_srcSystem(), msg.get_srcComponent(), seq)
        self._send(cid, req)

    def _on_mission_item(self, cid: object, msg: Message) -> None:
        up = self.links[cid].mission_up
        if up is None:
            return
        _, count, items = up
        if msg.seq != len(items):
            self._request_item(cid, msg, len(items))  # out of order: ask again (PX4 does)
            return
        if msg.command not in (
            mav.MAV_CMD_NAV_WAYPOINT,
            mav.MAV_CMD_NAV_TAKEOFF,
            mav.MAV_CMD_NAV_LAND,
            mav.MAV_CMD_NAV_RETURN_TO_LAUNCH,
            mav.MAV_CMD_NAV_LOITER_UNLIM,
            mav.MAV_CMD_DO_CHANGE_SPEED,
        ):
            self.links[cid].mission_up = None
            self._mission_ack(cid, msg, mav.MAV_MISSION_UNSUPPORTED)
            return
        items.append(msg)
        if len(items) < count:
            self._request_item(cid, msg, len(items))
            return
        self.links[cid].mission_up = None
        parsed: list[MissionItem] = []
        for it in items:
            x, y, z = self.physics.body.x, self.physics.body.y, self.physics.body.z
            if it.x or it.y:
                x, y, _ = self.origin.to_map(it.x / 1e7, it.y / 1e7, self.origin.alt_m)
            if it.frame in (
                mav.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            ):
                z = self.home[2] + it.z
            else:
                z = it.z - self.origin.alt_m
            b = self.physics.bounds
            if not (b[0] <= x <= b[1] and b[2] <= y <= b[3]):
                self.statustext(mav.MAV_SEVERITY_CRITICAL, f"Mission item {it.seq} outside")
                self._mission_ack(cid, msg, mav.MAV_MISSION_ERROR)
                return
            if it.command in _FLOWN_TO and z > self.ceiling_z + 1e-6:
                # PX4's feasibility check refuses items above the geofence (GF_MAX_VER_DIST)
                self.statustext(mav.MAV_SEVERITY_CRITICAL, f"Mission item {it.seq} too high")
                self._mission_ack(cid, msg, mav.MAV_MISSION_ERROR)
                return
            parsed.append(MissionItem(it.seq, it.command, x, y, z, it))
        self.mission = parsed
        self.mission_current = 0
        self._mission_ack(cid, msg, mav.MAV_MISSION_ACCEPTED)
        self.statustext(mav.MAV_SEVERITY_INFO, f"Mission accepted: {len(parsed)} items")

    def _mission_ack(self, cid: object, msg: Message, result: int) -> None:
        m = self.links[cid].codec.mav
        self._send(cid, m.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), result))

    def _on_mission_request_list(self, cid: object, msg: Message) -> None:
        m = self.links[cid].codec.mav
        count = m.mission_count_encode(
            msg.get_srcSystem(), msg.get_srcComponent(), len(self.mission)
        )
        self._send(cid, count)

    def _on_mission_request(self, cid: object, msg: Message) -> None:
        if not 0 <= msg.seq < len(self.mission):
            self._mission_ack(cid, msg, mav.MAV_MISSION_INVALID_SEQUENCE)
            return
        raw = self.mission[msg.seq].raw
        m = self.links[cid].codec.mav
        item = m.mission_item_int_encode(
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            raw.seq,
            raw.frame,
            raw.command,
            int(raw.seq == self.mission_current),
            raw.autocontinue,
            raw.param1,
            raw.param2,
            raw.param3,
            raw.param4,
            raw.x,
            raw.y,
            raw.z,
        )
        self._send(cid, item)

    def _on_mission_clear(self, cid: object, msg: Message) -> None:
        self.mission = []
        self.mission_current = 0
        if self.mode == "AUTO.MISSION":
            self._hold_here()
            self._set_mode("AUTO.LOITER")
        self._mission_ack(cid, msg, mav.MAV_MISSION_ACCEPTED)

    def _on_mission_set_current(self, cid: object, msg: Message) -> None:
        if 0 <= msg.seq < len(self.mission):
            self.mission_current = msg.seq

    # ------------------------------------------------------------------ parameters, timesync
    def _param_value(self, cid: object, name: str) -> None:
        names = self.params.names()
        m = self.links[cid].codec.mav
        value = float(getattr(self.params, name))
        msg = m.param_value_encode(
            name.encode(), value, mav.MAV_PARAM_TYPE_REAL32, len(names), names.index(name)
        )
        self._send(cid, msg)

    def _on_param_list(self, cid: object, msg: Message) -> None:
        for name in self.params.names():
            self._param_value(cid, name)

    def _on_param_read(self, cid: object, msg: Message) -> None:
        names = self.params.names()
        pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        if pid in names:
            self._param_value(cid, pid)
        elif 0 <= msg.param_index < len(names):
            self._param_value(cid, names[msg.param_index])

    def _on_param_set(self, cid: object, msg: Message) -> None:
        pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        if pid in self.params.names() and math.isfinite(msg.param_value):
            setattr(self.params, pid, float(msg.param_value))
            self._param_value(cid, pid)

    def _on_timesync(self, cid: object, msg: Message) -> None:
        if msg.tc1 == 0:
            m = self.links[cid].codec.mav
            self._send(cid, m.timesync_encode(int(self.time * 1e9), msg.ts1))

    # ------------------------------------------------------------------ simulation
    @property
    def truth(self) -> Truth:
        """Ground truth in the map frame (``GET /sim/{id}/truth``), as the AR.Drone sim's."""
        ph, b = self.physics, self.physics.body
        return Truth(
            t_s=self.time,
            x=b.x,
            y=b.y,
            z=b.z,
            yaw_rad=b.yaw_rad,
            vx=b.vx,
            vy=b.vy,
            vz=b.vz,
            roll=b.roll_rad,
            pitch=b.pitch_rad,
            battery_pct=ph.battery.pct,
            ctrl_state=CtrlState.DEFAULT if ph.emergency else ph.ctrl,
            flying=self._in_air,
            emergency=ph.emergency,
        )

    @property
    def _in_air(self) -> bool:
        return self.armed and self.landed_state != mav.MAV_LANDED_STATE_ON_GROUND

    def inject_fault(self, kind: str, **params: float) -> None:
        """``link_loss(duration_s)`` (every byte dropped both ways), ``battery(pct)``,
        ``wind(vx, vy)``, ``clear()`` — the kinds and REST aliases of ``SimDrone.inject_fault``."""
        aliases = {"battery_pct": "pct", "wind_x": "vx", "wind_y": "vy"}
        params = {aliases.get(k, k): v for k, v in params.items()}
        if kind == "link_loss":
            self._link_down_until = self.time + float(params["duration_s"])
        elif kind == "battery":
            self.physics.battery.drain_to(params.get("pct", 0.0))
        elif kind == "wind":
            self.physics.wind = (params.get("vx", 0.0), params.get("vy", 0.0))
        elif kind == "clear":
            self.physics.wind = (0.0, 0.0)
            self._link_down_until = -math.inf
        else:
            raise SimConfigError(f"unknown fault {kind!r}")

    def step(self, dt: float) -> None:
        """Advance ``dt`` seconds: failsafes, mode logic, position controller, physics, streams."""
        if dt <= 0:
            return
        self.time += dt
        if self._signing is not None:  # MAVProxy's signing module keeps to the wall clock too
            ts = signing_timestamp(self.signing_clock())
            if ts > self._signing.timestamp:
                self._signing.timestamp = ts
        self._failsafes()
        if self.armed and not self.physics.emergency:
            self._control(dt)
        self.physics.step(dt)
        self._landing_detector()
        self._streams()

    def _failsafes(self) -> None:
        p = self.params
        if (
            self._in_air
            and self._gcs_t is not None
            and not self._dl_lost
            and self.time - self._gcs_t > p.COM_DL_LOSS_T
        ):
            self._dl_lost = True
            act = int(p.NAV_DLL_ACT)
            if act:
                what = {1: "holding", 2: "returning", 3: "landing"}.get(act, "holding")
                self.statustext(
                    mav.MAV_SEVERITY_CRITICAL, f"Failsafe: no connection to GCS, {what}"
                )
                self._hold_here()
                self._set_mode(
                    {1: "AUTO.LOITER", 2: "AUTO.RTL", 3: "AUTO.LAND"}.get(act, "AUTO.LOITER")
                )
        if self.mode == "OFFBOARD" and self.time - self._offboard_t > p.COM_OF_LOSS_T:
            self.statustext(mav.MAV_SEVERITY_CRITICAL, "Failsafe: offboard lost, holding")
            self._hold_here()
            self._set_mode("AUTO.LOITER")
        pct = self.physics.battery.pct
        if self._in_air:
            if pct < p.BAT_EMERGEN_THR and self._bat_stage < 3:
                self._bat_stage = 3
                self.statustext(mav.MAV_SEVERITY_EMERGENCY, "Failsafe: battery emergency, landing")
                self._set_mode("AUTO.LAND")
            elif pct < p.BAT_CRIT_THR and self._bat_stage < 2:
                self._bat_stage = 2
                self.statustext(mav.MAV_SEVERITY_CRITICAL, "Failsafe: battery critical, returning")
                self._set_mode("AUTO.RTL")
            elif pct < p.BAT_LOW_THR and self._bat_stage < 1:
                self._bat_stage = 1
                self.statustext(mav.MAV_SEVERITY_WARNING, "Low battery level")

    def _control(self, dt: float) -> None:
        b = self.physics.body
        tx, ty, tz, tyaw = self._target
        vel: tuple[float, float, float] | None = None
        p = self.params
        if self.mode == "AUTO.TAKEOFF":
            if abs(b.z - tz) < 0.1:
                self._set_mode("AUTO.LOITER")
        elif self.mode == "AUTO.LAND":
            vel = (0.0, 0.0, -p.MPC_LAND_SPEED)
            tx, ty = b.x, b.y
        elif self.mode == "AUTO.RTL":
            hx, hy, hz, _ = self.home
            cruise = max(b.z, min(hz + p.RTL_RETURN_ALT, self.physics.bounds[5] - 1.0))
            if self._rtl_phase == "climb":
                tx, ty, tz = b.x, b.y, cruise
                if b.z >= cruise - 0.3:
                    self._rtl_phase, self._rtl_z = "return", cruise
            if self._rtl_phase == "return":
                tx, ty, tz = hx, hy, self._rtl_z
                if math.hypot(b.x - hx, b.y - hy) < 0.5:
                    self._rtl_phase = "land"
            if self._rtl_phase == "land":
                vel = (0.0, 0.0, -p.MPC_LAND_SPEED)
                tx, ty = hx, hy
            self._target = (tx, ty, tz, tyaw)
        elif self.mode == "AUTO.MISSION":
            tx, ty, tz = self._mission_step()
            if self.mode != "AUTO.MISSION":
                return
        elif self.mode == "OFFBOARD" and self._vel_sp is not None:
            vel = self._vel_sp
            self._target = (b.x, b.y, b.z, tyaw)
        self._fly_to(tx, ty, tz, tyaw, vel, dt)

    def _mission_step(self) -> tuple[float, float, float]:
        b = self.physics.body
        if self.mission_current >= len(self.mission):
            self._hold_here()
            self._set_mode("AUTO.LOITER")
            return self._target[:3]
        item = self.mission[self.mission_current]
        if item.command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._set_mode("AUTO.RTL")
            return b.x, b.y, b.z
        if item.command == mav.MAV_CMD_NAV_LAND:
            self._target = (item.x, item.y, b.z, self._target[3])
            if math.hypot(b.x - item.x, b.y - item.y) < self.params.NAV_ACC_RAD:
                self._set_mode("AUTO.LAND")
            return item.x, item.y, b.z
        if item.command == mav.MAV_CMD_DO_CHANGE_SPEED:
            if item.raw.param2 > 0:
                self._speed = min(float(item.raw.param2), self.params.MPC_XY_CRUISE)
            self._advance_mission()
            return b.x, b.y, b.z
        if item.command == mav.MAV_CMD_NAV_TAKEOFF:
            target = (b.x, b.y, item.z)
            done = abs(b.z - item.z) < 0.3
        else:
            target = (item.x, item.y, item.z)
            done = math.dist((b.x, b.y, b.z), target) < self.params.NAV_ACC_RAD
        if done:
            self._advance_mission()
        return target

    def _advance_mission(self) -> None:
        seq = self.mission_current
        m = next(iter(self.links.values())).codec.mav if self.links else None
        if m is not None:
            self._broadcast(m.mission_item_reached_encode(seq))
        self.mission_current += 1
        if self.mission_current >= len(self.mission):
            self.statustext(mav.MAV_SEVERITY_INFO, "Mission finished, loitering")
            last = self.mission[seq]
            self._set_mode("AUTO.LOITER")
            if last.command == mav.MAV_CMD_NAV_WAYPOINT:  # PX4 loiters at the last waypoint
                self._target = (last.x, last.y, last.z, self._target[3])
            else:
                self._hold_here()

    def _fly_to(
        self,
        tx: float,
        ty: float,
        tz: float,
        tyaw: float,
        vel: tuple[float, float, float] | None,
        dt: float,
    ) -> None:
        """Position → velocity → tilt, the physics' PCMD fractions (progressive)."""
        ph, b, p = self.physics, self.physics.body, self.params
        if ph.ctrl is CtrlState.LANDED:
            if vel is not None and vel[2] <= 0:
                return
            if tz <= b.z + 0.05 and vel is None:
                return
            ph.ctrl = CtrlState.FLYING
        if vel is None:
            kp = 0.95  # MPC_XY_P
            vx, vy = kp * (tx - b.x), kp * (ty - b.y)
            n = math.hypot(vx, vy)
            if n > self._speed:
                vx, vy = vx * self._speed / n, vy * self._speed / n
            vz = max(-p.MPC_Z_VEL_MAX_DN, min(p.MPC_Z_VEL_MAX_UP, 1.0 * (tz - b.z)))
        else:
            vx, vy, vz = vel
            n = math.hypot(vx, vy)
            if n > p.MPC_XY_CRUISE:
                vx, vy = vx * p.MPC_XY_CRUISE / n, vy * p.MPC_XY_CRUISE / n
            vz = max(-p.MPC_Z_VEL_MAX_DN, min(p.MPC_Z_VEL_MAX_UP, vz))
        g, kv, drag = 9.81, 1.8, ph.params.drag_per_s
        ax = kv * (vx - b.vx) + drag * vx
        ay = kv * (vy - b.vy) + drag * vy
        c, s = math.cos(b.yaw_rad), math.sin(b.yaw_rad)
        a_fwd, a_left = c * ax + s * ay, -s * ax + c * ay
        tilt = ph.params.euler_angle_max_rad
        pitch = math.atan(a_fwd / g)  # nose down positive
        roll = math.atan(-a_left / g)  # right wing down positive
        yaw_err = math.remainder(tyaw - b.yaw_rad, math.tau)
        yaw_rate = max(-1.0, min(1.0, 2.0 * yaw_err / ph.params.control_yaw_rad_s))
        ph.command(roll / tilt, -pitch / tilt, vz / ph.params.control_vz_max_m_s, -yaw_rate, True)

    def _landing_detector(self) -> None:
        ph, b, p = self.physics, self.physics.body, self.params
        floor = ph.bounds[4]
        on_ground = b.z <= floor + 0.05
        descending = ph.cmd_gaz < 0 or not self.armed
        if self.armed and on_ground and descending and ph.ctrl is not CtrlState.LANDED:
            ph.ctrl = CtrlState.LANDED
            ph.hover()
        if ph.ctrl is CtrlState.LANDED or ph.emergency:
            if self.landed_state != mav.MAV_LANDED_STATE_ON_GROUND:
                self.landed_state = mav.MAV_LANDED_STATE_ON_GROUND
                self._landed_since = self.time
                if self.armed:
                    self.statustext(mav.MAV_SEVERITY_INFO, "Landing detected")
            since = self._landed_since if self._took_off else self._armed_since
            limit = p.COM_DISARM_LAND if self._took_off else p.COM_DISARM_PRFLT
            if self.armed and since is not None and self.time - since > limit:
                self._disarm("auto disarm")
                self._hold_here()
                self._set_mode("AUTO.LOITER")
                self._rtl_phase = ""
        elif self.mode == "AUTO.TAKEOFF":
            self.landed_state = mav.MAV_LANDED_STATE_TAKEOFF
        elif self.mode == "AUTO.LAND" or (self.mode == "AUTO.RTL" and self._rtl_phase == "land"):
            self.landed_state = mav.MAV_LANDED_STATE_LANDING
        else:
            self.landed_state = mav.MAV_LANDED_STATE_IN_AIR

    # ------------------------------------------------------------------ telemetry
    def _streams(self) -> None:
        for cid, link in self.links.items():
            for name, hz in link.rates_hz.items():
                if hz <= 0:
                    continue
                due = link.next_t.get(name, self.time)
                if self.time + 1e-9 >= due:
                    link.next_t[name] = max(due + 1.0 / hz, self.time)
                    self._send(cid, self.message(name, link.codec.mav))

    def _send_requested(self, cid: object, msg_id: int) -> None:
        m = self.links[cid].codec.mav
        if msg_id == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            caps = (
                mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mav.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION
            )
            version = (1 << 24) | (15 << 16) | (0 << 8) | 255  # 1.15.0 release
            self._send(
                cid,
                m.autopilot_version_encode(
                    caps, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.system_id
                ),
            )
        elif msg_id in _MSG_NAMES:
            self._send(cid, self.message(_MSG_NAMES[msg_id], m))

    def message(self, name: str, m: Any) -> Message:
        """The current ``name`` message (built with ``m``, a pymavlink MAVLink)."""
        ph, b = self.physics, self.physics.body
        t_ms = int(self.time * 1000) & 0xFFFFFFFF
        if name == "HEARTBEAT":
            base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
            if self.armed:
                base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
            if self.mode.startswith("AUTO"):
                base |= mav.MAV_MODE_FLAG_AUTO_ENABLED | mav.MAV_MODE_FLAG_GUIDED_ENABLED
            status = mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY
            if self._dl_lost or self._bat_stage >= 2:
                status = mav.MAV_STATE_CRITICAL
            if ph.emergency:
                status = mav.MAV_STATE_EMERGENCY
            return m.heartbeat_encode(
                mav.MAV_TYPE_QUADROTOR,
                mav.MAV_AUTOPILOT_PX4,
                base,
                px4_custom_mode(self.mode),
                status,
            )
        if name == "SYS_STATUS":
            pct = ph.battery.pct
            volts = int((14.0 + 2.8 * pct / 100.0) * 1000)  # 4S LiPo, 3.5–4.2 V per cell
            return m.sys_status_encode(
                SENSORS,
                SENSORS,
                SENSORS,
                200,
                volts,
                1500 if self.armed else 50,
                int(pct),
                0,
                0,
                0,
                0,
                0,
                0,
            )
        if name == "EXTENDED_SYS_STATE":
            return m.extended_sys_state_encode(mav.MAV_VTOL_STATE_UNDEFINED, self.landed_state)
        lat, lon, alt = self.origin.to_geo(b.x, b.y, b.z)
        if name == "GPS_RAW_INT":
            speed = math.hypot(b.vx, b.vy)
            cog = math.degrees(math.atan2(b.vx, b.vy)) % 360.0
            return m.gps_raw_int_encode(
                int(self.time * 1e6),
                mav.GPS_FIX_TYPE_3D_FIX,
                round(lat * 1e7),
                round(lon * 1e7),
                round(alt * 1000),
                80,
                120,
                int(speed * 100),
                int(cog * 100),
                12,
            )
        if name == "GLOBAL_POSITION_INT":
            n, e, d = enu_to_ned(b.vx, b.vy, b.vz)
            hdg = math.degrees(yaw_enu_to_ned(b.yaw_rad)) % 360.0
            return m.global_position_int_encode(
                t_ms,
                round(lat * 1e7),
                round(lon * 1e7),
                round(alt * 1000),
                round((b.z - self.home[2]) * 1000),
                int(n * 100),
                int(e * 100),
                int(d * 100),
                int(hdg * 100),
            )
        if name == "LOCAL_POSITION_NED":
            ox, oy, oz = self.local_origin
            n, e, d = enu_to_ned(b.x - ox, b.y - oy, b.z - oz)
            vn, ve, vd = enu_to_ned(b.vx, b.vy, b.vz)
            return m.local_position_ned_encode(t_ms, n, e, d, vn, ve, vd)
        if name == "ATTITUDE":
            # NED body (FRD): roll right-wing-down +, pitch nose-up +, yaw clockwise from north
            return m.attitude_encode(
                t_ms, b.roll_rad, -b.pitch_rad, yaw_enu_to_ned(b.yaw_rad), 0.0, 0.0, -b.yaw_rate
            )
        if name == "BATTERY_STATUS":
            pct = ph.battery.pct
            cell = int((3.5 + 0.7 * pct / 100.0) * 1000)
            return m.battery_status_encode(
                0,
                mav.MAV_BATTERY_FUNCTION_ALL,
                mav.MAV_BATTERY_TYPE_LIPO,
                2500,
                [cell] * 4 + [65535] * 6,
                1500 if self.armed else 50,
                -1,
                -1,
                int(pct),
                int(ph.battery.flight_time_s * pct / 100.0),
            )
        if name == "HOME_POSITION":
            hx, hy, hz, hyaw = self.home
            hlat, hlon, halt = self.origin.to_geo(hx, hy, hz)
            ox, oy, oz = self.local_origin
            hn, he, hd = enu_to_ned(hx - ox, hy - oy, hz - oz)  # home in the local frame
            q = [math.cos(yaw_enu_to_ned(hyaw) / 2), 0.0, 0.0, math.sin(yaw_enu_to_ned(hyaw) / 2)]
            return m.home_position_encode(
                round(hlat * 1e7),
                round(hlon * 1e7),
                round(halt * 1000),
                hn,
                he,
                hd,
                q,
                0.0,
                0.0,
                0.0,
            )
        if name == "MISSION_CURRENT":
            return m.mission_current_encode(self.mission_current, len(self.mission))
        raise KeyError(name)
