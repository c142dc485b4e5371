"""Telemetry streams of the simulated autopilot: the messages PX4 sends, their rates per link
(SET_MESSAGE_INTERVAL, REQUEST_MESSAGE), AUTOPILOT_VERSION, and TIMESYNC answers."""

from __future__ import annotations

import math
from typing import Any

from drone.mavlink.codec import Message, mav
from drone.mavlink.geo import enu_to_ned, yaw_enu_to_ned
from drone.mavlink.modes import px4_custom_mode
from drone.mavlink.sim.core import (
    DEFAULT_RATES_HZ,
    RESULT_ACCEPTED,
    RESULT_DENIED,
    RESULT_UNSUPPORTED,
    AutopilotCore,
)

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
MSG_IDS = {name: getattr(mav, f"MAVLINK_MSG_ID_{name}") for name in DEFAULT_RATES_HZ}
MSG_NAMES = {v: k for k, v in MSG_IDS.items()}


class StreamsService(AutopilotCore):
    """Periodic telemetry per link, requested messages and TIMESYNC."""

    def _set_interval(self, msg: Message, msg_id: int, interval_us: float) -> int:
        name = MSG_NAMES.get(msg_id)
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
        elif msg_id in MSG_NAMES:
            self._send(cid, self.message(MSG_NAMES[msg_id], m))

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

    def _on_timesync(self, cid: object, msg: Message) -> None:
        if msg.tc1 == 0:
            m = self.links[cid].codec.mav
            self._send(cid, m.timesync_encode(int(self.time * 1e9), msg.ts1))
