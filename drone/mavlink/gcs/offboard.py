"""Offboard setpoints: SET_POSITION_TARGET_LOCAL_NED streamed at ``setpoint_hz`` while a
velocity or position target is held; a released velocity stream ends with zero velocity."""

from __future__ import annotations

import math

from drone.mavlink.codec import mav
from drone.mavlink.gcs.core import GcsCore


class OffboardService(GcsCore):
    """Hold, stream and release a local-NED velocity or position target."""

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
