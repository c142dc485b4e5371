"""State every service of the simulated autopilot shares: parameters, links, mode, home.

:class:`AutopilotCore` holds the vehicle's state (physics, links, mode, home, mission list,
hold point) and the few operations every service uses: sending on a link, STATUSTEXT, setting
the mode, the ceiling. The services (``commands``, ``mission``, ``params``, ``streams``,
``flight``) build on it; ``drone.mavlink.sim.autopilot.SimAutopilot`` composes them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drone.mavlink.codec import Codec, Message, mav, signing_state, signing_timestamp
from drone.mavlink.geo import Origin
from drone.sim.battery import Battery
from drone.sim.errors import SimConfigError
from drone.sim.physics import Body, FlightParams, Physics, as_box

RESULT_ACCEPTED: int = int(mav.MAV_RESULT_ACCEPTED)  # typed copies (pymavlink is untyped)
RESULT_DENIED: int = int(mav.MAV_RESULT_DENIED)
RESULT_UNSUPPORTED: int = int(mav.MAV_RESULT_UNSUPPORTED)
DEFAULT_ORIGIN = Origin(47.397742, 8.545594, 488.0)  # PX4 SITL's default home (Zurich)
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


class AutopilotCore:
    """The shared state and link plumbing of :class:`~drone.mavlink.sim.autopilot.SimAutopilot`
    (its constructor arguments are documented there)."""

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

    # ------------------------------------------------------------------ mode, ceiling
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

    def _set_mode(self, name: str) -> None:
        if name == "AUTO.RTL":
            self._rtl_phase = "climb"
        if name != "OFFBOARD":
            self._vel_sp = None
        self.mode = name

    def _hold_here(self) -> None:
        b = self.physics.body
        self._target = (b.x, b.y, b.z, b.yaw_rad)

    @property
    def _in_air(self) -> bool:
        return self.armed and self.landed_state != mav.MAV_LANDED_STATE_ON_GROUND
