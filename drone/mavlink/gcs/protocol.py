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

import math
from dataclasses import replace

from drone.mavlink.codec import Message, mav, signing_timestamp
from drone.mavlink.gcs.commands import FORCE_DISARM
from drone.mavlink.gcs.events import LinkRestored, MissionItemReached, OtherVehicle
from drone.mavlink.gcs.heartbeat import HeartbeatService
from drone.mavlink.gcs.mission import MissionService
from drone.mavlink.gcs.offboard import OffboardService
from drone.mavlink.gcs.telemetry import LANDED_STATES, TelemetryService, implausible
from drone.mavlink.modes import mode_name


class GcsProtocol(HeartbeatService, TelemetryService, OffboardService, MissionService):
    """See the module docstring. One microservice per module, each a layer over
    :class:`~drone.mavlink.gcs.core.GcsCore` (the shared state): ``telemetry`` (STATUSTEXT),
    ``commands``, ``heartbeat`` (over ``commands``: discovery requests streams), ``offboard``,
    ``mission``; this class adds the input dispatch, ``kill`` and the ``tick``.

    ``signing_key`` signs every frame and accepts only signed ones; ``signing_clock`` (Unix
    time) is read for the signing timestamps only, which start at it and are kept at least at
    it (``Codec.keep_up``), so the vehicle's "new stream at most a minute old" check passes.
    """

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
            t = replace(t, landed_state=LANDED_STATES.get(msg.landed_state, "UNDEFINED"))
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

    # ------------------------------------------------------------------ safety
    def kill(self, now: float | None = None) -> int:
        """Motors off now (force disarm), ahead of anything queued."""
        self.stop_setpoints(now)
        return self.command(
            mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, float(FORCE_DISARM), now=now, urgent=True
        )

    # ------------------------------------------------------------------ time
    def tick(self, now: float) -> None:
        """Heartbeat, retries, setpoint stream, upload timeouts, link watchdog."""
        self._now = now
        if self.codec.signed:
            self.codec.keep_up(signing_timestamp(self.signing_clock()))
        self._heartbeat(now)
        self._check_commands(now)
        self._check_upload(now)
        if self._setpoint is not None and now >= self._next_sp:
            self._stream(now)
        self._watchdog(now)
