"""Flight control of the simulated autopilot: arming, take-off, mode requests, offboard
setpoints, failsafes, the position controller and the landing detector (PX4's commander and
multicopter position control in miniature; see the ``autopilot`` module docstring)."""

from __future__ import annotations

import math

from drone.ardrone.navdata import CtrlState
from drone.mavlink.codec import Message, mav
from drone.mavlink.geo import yaw_ned_to_enu
from drone.mavlink.sim.core import RESULT_ACCEPTED, RESULT_DENIED
from drone.mavlink.sim.mission import AutopilotMissionService


class FlightService(AutopilotMissionService):
    """Arming, take-off, modes, offboard, failsafes and the position controller."""

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
