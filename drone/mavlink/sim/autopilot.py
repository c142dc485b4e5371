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
  (``drone.mavlink.sim.commands``): arm/disarm (disarm in the air is DENIED unless forced
  with 21196), take-off (param7 AMSL; NaN: MIS_TAKEOFF_ALT, 2.5 m, above the vehicle), land, RTL,
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
from collections.abc import Callable

from drone.ardrone.navdata import CtrlState
from drone.mavlink.codec import Message, mav, signing_timestamp
from drone.mavlink.sim.commands import AutopilotCommandService
from drone.mavlink.sim.params import ParamsService
from drone.sim.drone import Truth
from drone.sim.errors import SimConfigError

REFUSED_UNSIGNED = b"Refused: MAVLink 2 signing required"  # STATUSTEXT, <= 50 bytes


class SimAutopilot(AutopilotCommandService, ParamsService):
    """See the module docstring. One service per module, each a layer over
    :class:`~drone.mavlink.sim.core.AutopilotCore` (the shared state): ``streams``, ``params``,
    ``mission``, ``flight`` (over ``mission``), ``commands`` (over ``flight`` and ``streams``);
    this class adds the input dispatch (message type → service handler) and the time step.

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
