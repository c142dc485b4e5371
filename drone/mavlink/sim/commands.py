"""The command protocol of the simulated autopilot: COMMAND_LONG/COMMAND_INT answered with
COMMAND_ACK, retransmissions answered without acting twice, one handler per command in a
table (:meth:`AutopilotCommandService._command_table`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cached_property

from drone.mavlink.codec import Message, mav
from drone.mavlink.geo import yaw_ned_to_enu
from drone.mavlink.modes import px4_mode_name
from drone.mavlink.sim.core import RESULT_ACCEPTED, RESULT_DENIED, RESULT_UNSUPPORTED
from drone.mavlink.sim.flight import FlightService
from drone.mavlink.sim.streams import MSG_NAMES, StreamsService

FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force (PX4 commander)


class AutopilotCommandService(FlightService, StreamsService):
    """COMMAND_LONG/COMMAND_INT: dedupe, dispatch through the command table, acknowledge."""

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

    @cached_property
    def _commands(self) -> dict[int, Callable[[Message], int]]:
        return self._command_table()

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
        known = MSG_NAMES.keys() | {mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION}
        if msg.command == mav.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) not in known:
            return RESULT_UNSUPPORTED
        return RESULT_ACCEPTED
