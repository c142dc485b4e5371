"""Heartbeat and connection, ground-station side: our 1 Hz GCS heartbeat, discovery of the
vehicle (streams and parameters requested then), and the link watchdog with the autopilot's
own data-link failsafe in words."""

from __future__ import annotations

from dataclasses import replace

from drone.mavlink.codec import Message, mav
from drone.mavlink.gcs.commands import CommandService
from drone.mavlink.gcs.core import HEARTBEAT_PERIOD_S
from drone.mavlink.gcs.events import LinkLost, VehicleFound

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
AUTOPILOTS = {mav.MAV_AUTOPILOT_PX4: "PX4", mav.MAV_AUTOPILOT_ARDUPILOTMEGA: "ArduPilot"}


class HeartbeatService(CommandService):
    """Send heartbeats, pick the vehicle from its first one, notice when they stop."""

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

    def _heartbeat(self, now: float) -> None:
        """Our GCS heartbeat, once per HEARTBEAT_PERIOD_S."""
        if now >= self._next_hb:
            self._next_hb = now + HEARTBEAT_PERIOD_S
            self._send(
                self.m.heartbeat_encode(
                    mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE
                )
            )

    def _watchdog(self, now: float) -> None:
        """LinkLost once the vehicle's heartbeats stop for ``link_timeout_s``."""
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
