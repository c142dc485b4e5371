"""``ARDroneVehicle``: one AR.Drone 2.0 — driver, marker perception, EKF, the paper's PID and a
setpoint; it implements :class:`drone.vehicle.Vehicle`.

The same object flies in real time and in lockstep (DESIGN §3):

* inputs: ``on_driver_event(event)`` (navdata, link lost/restored from
  ``drone.ardrone.driver``), ``on_frame(frame, t)`` (camera images), ``control_step(now, dt)``
  (the controller, called by :class:`~drone.control.loop.ControlLoop` at 100 Hz in real time or
  by :class:`~drone.lockstep.LockstepRig` on a virtual clock);
* commands (thread-safe, any thread): ``takeoff() land() emergency() reset() hover()
  jog(linear_x, linear_y, linear_z, angular_z) set_setpoint(Setpoint | None)``;
* output: ``snapshot() -> VehicleSnapshot`` (immutable; what telemetry, the task manager and
  the dialog read) and PCMD commands to the driver.

Jog follows ardrone_autonomy's ``/cmd_vel``: fractions in [−1, 1], PCMD roll = −linear.y,
pitch = −linear.x, gaz = linear.z, yaw = −angular.z; all zero → hover. A jog replaces the
setpoint, and ``add_jog_listener`` callbacks learn of it (the task manager cancels its task).
Near the world's walls, floor and ceiling (``drone.limits``) each controller tick slows the
jog towards them, then stops and brakes it; ``snapshot().jog_limit`` says why (the ANS tells
the operator).

Real time: ``await vehicle.start(driver)`` with the asyncio ``ARDroneDriver`` (already
started) hooks its ``on_event`` (chaining any existing callback), feeds ``driver.latest_frame``
to the perception worker thread and starts the 100 Hz control thread; ``await vehicle.stop()``
lands (or hovers when ``land=False``) and stops them.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from drone.ardrone.frame_clock import FrameClock
from drone.ardrone.navdata import (
    TAG_DEMO,
    TAG_GPS,
    TAG_PRESSURE_RAW,
    CtrlState,
    DroneState,
    Gps,
    Navdata,
)
from drone.control.clock import Clock, MonotonicClock
from drone.control.loop import ControlLoop
from drone.control.pid import DroneLimits, PaperGains, PaperPID, PcmdCommand, Setpoint, wrap_angle
from drone.limits import FlightLimits, limits_of
from drone.perception.ekf import EkfConfig, Estimate, ExtendedKalmanFilter, NavdataInput
from drone.perception.markers import FrameResult, MarkerLocaliser, PerceptionWorker, draw_overlay
from drone.vehicle import MarkerSeen, VehicleMode, VehicleSnapshot

__all__ = ["ARDroneVehicle", "Commander", "navdata_options"]

FLYING_STATES = (CtrlState.FLYING, CtrlState.HOVERING, CtrlState.GOTOFIX)
ALTITUDE_MAX_DEFAULT_MM = 3000  # control:altitude_max firmware default (ARDroneLib config_keys.h)


def navdata_options(world: Any) -> int:
    """``general:navdata_options`` bit mask (one bit per option tag, navdata_keys.h): demo and
    raw pressure always, GPS where the world has a GPS origin."""
    mask = (1 << TAG_DEMO) | (1 << TAG_PRESSURE_RAW)
    if getattr(world, "gps_origin", None) is not None:
        mask |= 1 << TAG_GPS
    return mask


class Commander(Protocol):
    """What the vehicle needs from a driver (``DriverProtocol`` and ``ARDroneDriver`` both fit)."""

    def takeoff(self) -> None: ...
    def land(self) -> None: ...
    def emergency(self) -> None: ...
    def reset(self) -> None: ...
    def hover(self) -> None: ...
    def move(self, roll: float, pitch: float, gaz: float, yaw: float) -> None: ...


class ARDroneVehicle:
    """One drone; see the module docstring.

    Args:
        name: ``uav1``…
        world: the map (``drone.sim.world.World``): marker poses for localisation.
        commander: the driver to command (``DriverProtocol`` in lockstep, ``ARDroneDriver`` live).
        camera: front camera model (``drone.camera.CameraModel``); None disables perception.
        clock: time source for ``snapshot``/ages (virtual in lockstep).
    """

    # The AR.Drone's own hover holds attitude over optical flow and drifts; the position
    # controller holds a hover at the estimate instead (server.tasks.flight.HoverTask).
    holds_position = False

    def __init__(
        self,
        name: str,
        world: Any,
        commander: Commander | None = None,
        *,
        camera: Any | None = None,
        clock: Clock | None = None,
        gains: PaperGains | None = None,
        limits: DroneLimits | None = None,
        ekf_config: EkfConfig | None = None,
        link_timeout_s: float = 0.5,
    ) -> None:
        self.name = name
        self.world = world
        self.commander = commander
        self.camera = camera
        self.clock: Clock = clock or MonotonicClock()
        self.pid = PaperPID(gains, limits)
        self.ekf = ExtendedKalmanFilter(ekf_config, t0=self.clock.now())
        self.frame_clock = FrameClock()  # PaVE timestamps -> capture times (real time only)
        self.localiser = MarkerLocaliser(world, camera) if camera is not None else None
        self.link_timeout_s = link_timeout_s
        self.limits: FlightLimits | None = (
            limits_of(world) if world is not None and hasattr(world, "bounds") else None
        )
        self._jog_limit = ""
        self._navdata_doubt = ""  # the driver's NavdataDoubt reason until NavdataTrusted
        self._lock = threading.RLock()  # commands vs. the control thread
        self._mode = VehicleMode.IDLE
        self._setpoint: Setpoint | None = None
        self._jog: PcmdCommand | None = None
        self._jog_listeners: list[Callable[[], None]] = []
        self._nav_listeners: list[Callable[[Navdata, float], None]] = []
        self._result_listeners: list[Callable[[FrameResult], None]] = []
        self._nav: Navdata | None = None
        self._nav_t: float | None = None
        self._prev_psi: tuple[float, float] | None = None  # (t, yaw) for the yaw rate
        self._link_ok = False
        self._markers: tuple[MarkerSeen, ...] = ()
        self._last_marker_t: float | None = None
        self._last_gps: tuple[float, float, float, int] | None = None
        self._last_gps_t: float | None = None
        self._temperature_c: float | None = None
        self._last_result: FrameResult | None = None
        self._last_frame: np.ndarray | None = None
        self._last_cmd: PcmdCommand | None = None
        self._worker: PerceptionWorker | None = None
        self._loop: ControlLoop | None = None
        self._driver: Any | None = None
        self._frame_task: asyncio.Task[None] | None = None
        self.frames_seen = 0

    # ------------------------------------------------------------------ commands
    def _cmd(self) -> Commander:
        if self.commander is None:
            raise RuntimeError(f"vehicle {self.name} has no driver")
        return self.commander

    def takeoff(self) -> None:
        """Take off (the drone climbs to ~0.8 m and hovers); resets the integral term."""
        with self._lock:
            self.pid.reset()
            self._mode = VehicleMode.IDLE
            self._setpoint = None
            self._jog = None
            self._cmd().takeoff()

    def land(self) -> None:
        """Land now (jumps the driver's queue, DESIGN §5)."""
        with self._lock:
            self._mode = VehicleMode.LANDING
            self._setpoint = None
            self._jog = None
            self._cmd().land()

    def emergency(self) -> None:
        """Cut the motors now."""
        with self._lock:
            self._mode = VehicleMode.EMERGENCY
            self._setpoint = None
            self._jog = None
            self._cmd().emergency()

    def reset(self) -> None:
        """Leave the emergency state (the drone must be on the floor)."""
        with self._lock:
            self._mode = VehicleMode.IDLE
            self._cmd().reset()

    def hover(self) -> None:
        """Stop: no setpoint, no jog; the drone holds position on its own (PCMD flag 0)."""
        with self._lock:
            if self._mode not in (VehicleMode.LANDING, VehicleMode.EMERGENCY):
                self._mode = VehicleMode.IDLE
            self._setpoint = None
            self._jog = None
            self._cmd().hover()

    def jog(self, linear_x: float, linear_y: float, linear_z: float, angular_z: float) -> None:
        """Manual flight with ``/cmd_vel`` fractions (ardrone_autonomy semantics; module doc).

        Raises:
            ValueError: a value is NaN or infinite.
        """
        vals = (linear_x, linear_y, linear_z, angular_z)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"jog values must be finite, got {vals}")
        c = [max(-1.0, min(1.0, float(v))) for v in vals]
        with self._lock:
            if self._mode in (VehicleMode.LANDING, VehicleMode.EMERGENCY):
                return
            self._setpoint = None
            if c == [0.0, 0.0, 0.0, 0.0]:
                self._jog = None
                self._mode = VehicleMode.IDLE
                self._cmd().hover()
            else:
                self._jog = PcmdCommand(roll=-c[1], pitch=-c[0], gaz=c[2], yaw=-c[3])
                self._mode = VehicleMode.MANUAL
            listeners = list(self._jog_listeners)
        for cb in listeners:
            cb()

    def add_jog_listener(self, cb: Callable[[], None]) -> None:
        """Call ``cb()`` after every jog (the task manager cancels its running task)."""
        self._jog_listeners.append(cb)

    def add_navdata_listener(self, cb: Callable[[Navdata, float], None]) -> None:
        """Call ``cb(navdata, now)`` after each navdata packet has updated the estimate."""
        self._nav_listeners.append(cb)

    def add_result_listener(self, cb: Callable[[FrameResult], None]) -> None:
        """Call ``cb(result)`` after each processed camera frame (perception worker thread)."""
        self._result_listeners.append(cb)

    def set_setpoint(self, setpoint: Setpoint | None) -> None:
        """Fly to ``setpoint`` with the PID (None: hover in place)."""
        with self._lock:
            if self._mode in (VehicleMode.LANDING, VehicleMode.EMERGENCY):
                if setpoint is None:
                    self._setpoint = None
                return
            self._setpoint = setpoint
            self._jog = None
            self._mode = VehicleMode.AUTO if setpoint is not None else VehicleMode.IDLE

    @property
    def setpoint(self) -> Setpoint | None:
        return self._setpoint

    @property
    def estimate(self) -> Estimate:
        return self.ekf.latest

    # ------------------------------------------------------------------ inputs
    def on_driver_event(self, event: Any) -> None:
        """Feed a ``drone.ardrone.driver`` event (NavdataReceived, LinkLost, LinkRestored…)."""
        kind = type(event).__name__
        if kind == "NavdataReceived":
            self.on_navdata(event.navdata, event.now)
        elif kind == "LinkLost":
            self._link_ok = False
        elif kind == "NavdataDoubt":
            self._navdata_doubt = str(event.reason)
        elif kind == "NavdataTrusted":
            self._navdata_doubt = ""
        elif kind in ("LinkRestored", "HandshakeDone"):
            self._link_ok = True
            if kind == "HandshakeDone":
                self.configure_drone()

    def configure_drone(self) -> None:
        """Configure the drone for this world once the link is up:

        * ``general:navdata_options``: demo, the barometer (tag 21: pressure and temperature,
          shown in the console) and, where the world has a GPS origin, GPS (tag 27);
        * ``control:altitude_max`` raised to the world's ceiling when it allows more than the
          firmware's 3000 mm default (outdoor fields), so the drone can fly what is accepted.
        """
        config = getattr(self.commander, "config", None)
        if config is None:
            return
        with contextlib.suppress(Exception):  # not connected yet: HandshakeDone calls again
            config("general:navdata_options", str(navdata_options(self.world)))
            if self.limits is not None:
                mm = round(self.limits.ceiling_m * 1000.0)
                if mm > ALTITUDE_MAX_DEFAULT_MM:
                    config("control:altitude_max", str(mm))

    def on_navdata(self, nav: Navdata, now: float) -> None:
        """One navdata packet at ``now``: body state → EKF predict + update."""
        self._nav = nav
        self._nav_t = now
        self._link_ok = True
        if nav.pressure is not None:  # kept between packets that do not carry the option
            self._temperature_c = nav.pressure.temperature_c
        if nav.demo is None:
            return
        body = nav.to_body()
        if self._mode is VehicleMode.LANDING and body.ctrl_state == CtrlState.LANDED:
            with self._lock:
                self._mode = VehicleMode.IDLE
        if self._mode is VehicleMode.EMERGENCY and body.ctrl_state == CtrlState.LANDED:
            with self._lock:
                self._mode = VehicleMode.IDLE
        rate = 0.0
        if self._prev_psi is not None and now > self._prev_psi[0]:
            rate = wrap_angle(body.yaw_rad - self._prev_psi[1]) / (now - self._prev_psi[0])
        self._prev_psi = (now, body.yaw_rad)
        if not body.flying:
            rate = 0.0
        landed = not body.flying and body.ctrl_state == CtrlState.LANDED
        # Motors cut (the EMERGENCY state bit): the drone falls; the EKF takes navdata ungated.
        unpowered = bool(nav.state & DroneState.EMERGENCY)
        self.ekf.update_navdata(
            NavdataInput(
                now,
                body.vx_m_s,
                body.vy_m_s,
                body.vz_m_s,
                body.altitude_m,
                rate,
                landed,
                unpowered,
            )
        )
        if nav.gps is not None:
            self._note_gps(nav.gps, now)
        for cb in self._nav_listeners:
            cb(nav, now)

    def _note_gps(self, gps: Gps, now: float) -> None:
        """A GPS option carrying a valid fix: when the receiver last gave one (the fleet's LTM
        fuses the fixes into the EKF, ``server.fleet.ltm``; the ANS reads how fresh they are).
        The option repeats the receiver's last fix in every packet: a new one has another time
        stamp (``lastFrameTimestamp``) or position."""
        fix = (gps.latitude_deg, gps.longitude_deg, gps.elevation_m, gps.last_frame_timestamp)
        if not gps.data_available or fix == self._last_gps:
            return
        if all(math.isfinite(v) for v in fix):
            self._last_gps = fix
            self._last_gps_t = now

    def on_frame(self, frame: np.ndarray, t: float) -> None:
        """A camera frame captured at ``t``: to the worker thread if running, else processed now."""
        self._last_frame = frame
        self.frames_seen += 1
        if self.localiser is None:
            return
        if self._worker is not None:
            self._worker.submit(frame, t)
        else:
            self._perceive(frame, t)

    def _attitude(self) -> tuple[float, float]:
        nav = self._nav
        if nav is None or nav.demo is None:
            return 0.0, 0.0
        b = nav.to_body()
        return b.roll_rad, b.pitch_rad

    def _perception_context(self) -> tuple[float, float, float | None]:
        """(roll, pitch) from navdata and the EKF's yaw as a prior (None before localisation)."""
        roll, pitch = self._attitude()
        est = self.ekf.latest
        return roll, pitch, (est.yaw_rad if est.localised else None)

    def _perceive(self, frame: np.ndarray, t: float) -> None:
        assert self.localiser is not None
        roll, pitch, prior = self._perception_context()
        self._on_result(self.localiser.process(frame, t, roll, pitch, prior))

    def _on_result(self, result: FrameResult) -> None:
        seen = []
        for det in result.detections:
            if det.fix is None:
                continue
            self.ekf.update_marker(det.fix)
            m = self.localiser.markers[det.marker_id] if self.localiser else None
            if m is None:
                continue
            seen.append(
                MarkerSeen(
                    det.marker_id,
                    det.distance_m,
                    det.fix.x,
                    det.fix.y,
                    det.fix.z,
                    det.fix.yaw_rad,
                    float(m.position[0]),
                    float(m.position[1]),
                    float(m.position[2]),
                    float(m.yaw_rad),
                )
            )
        self._markers = tuple(seen)
        if seen:
            self._last_marker_t = result.t
        self._last_result = result
        for cb in self._result_listeners:
            cb(result)

    # ------------------------------------------------------------------ control
    def control_step(self, now: float, dt: float) -> PcmdCommand | None:
        """One controller tick (100 Hz): jog, PID towards the setpoint, or hover.

        Sends nothing unless navdata says the drone is flying (take-off, landing and the floor
        belong to the drone's own controller). Returns the command sent, if any.
        """
        nav = self._nav
        if nav is None or nav.demo is None or self.commander is None:
            return None
        if nav.demo.major not in FLYING_STATES:
            return None
        with self._lock:
            mode, sp, jog = self._mode, self._setpoint, self._jog
            if mode in (VehicleMode.LANDING, VehicleMode.EMERGENCY):
                return None
            if mode is VehicleMode.MANUAL and jog is not None:
                cmd = self._clamped(jog, nav)
            elif mode is VehicleMode.AUTO and sp is not None:
                cmd = self.pid.step(_Extrapolated(self.ekf.latest, now), sp, max(dt, 0.0))
            else:
                cmd = PcmdCommand.hold()
            if mode is not VehicleMode.MANUAL:
                self._jog_limit = ""
            if cmd.hover:
                self.commander.hover()
            else:
                self.commander.move(cmd.roll, cmd.pitch, cmd.gaz, cmd.yaw)
            self._last_cmd = cmd
        return cmd

    def _clamped(self, jog: PcmdCommand, nav: Navdata) -> PcmdCommand:
        """The jog limited near the world's walls, floor and ceiling (``drone.limits``).

        Height comes from the ultrasound (navdata), the planar position and velocities from the
        estimate; before the first marker fix only the height is limited (no position known).
        """
        lim = self.limits
        if lim is None:
            return jog
        est = self.ekf.latest
        c, s = math.cos(est.yaw_rad), math.sin(est.yaw_rad)
        fwd, left = -jog.pitch, -jog.roll
        east, north = c * fwd - s * left, s * fwd + c * left
        alt = nav.to_body().altitude_m
        if est.localised:
            out = lim.clamp_jog(est.x, est.y, alt, est.vx, est.vy, est.vz, east, north, jog.gaz)
        else:
            far = (lim.x_min + lim.x_max) / 2, (lim.y_min + lim.y_max) / 2
            out = lim.clamp_jog(*far, alt, 0.0, 0.0, est.vz, 0.0, 0.0, jog.gaz)
            out = type(out)(east, north, out.up, out.reasons)
        self._jog_limit = "; ".join(out.reasons)
        if not out.reasons:
            return jog
        fwd, left = c * out.east + s * out.north, -s * out.east + c * out.north
        return PcmdCommand(roll=-left, pitch=-fwd, gaz=out.up, yaw=jog.yaw)

    # ------------------------------------------------------------------ output
    def snapshot(self) -> VehicleSnapshot:
        now = self.clock.now()
        est = self.ekf.latest
        nav = self._nav
        body = nav.to_body() if nav is not None and nav.demo is not None else None
        ctrl = body.ctrl_state if body is not None else CtrlState.DEFAULT
        ctrl_name = ctrl.name if isinstance(ctrl, CtrlState) else str(ctrl)
        emergency = bool(nav is not None and nav.state & DroneState.EMERGENCY)
        age = None if self._nav_t is None else max(0.0, now - self._nav_t)
        link_ok = self._link_ok and age is not None and age < self.link_timeout_s
        return VehicleSnapshot(
            name=self.name,
            t=now,
            ctrl_state=ctrl_name,
            flying=bool(body.flying) if body is not None else False,
            emergency=emergency,
            battery_pct=body.battery_pct if body is not None else 0.0,
            altitude_m=body.altitude_m if body is not None else 0.0,
            x=est.x,
            y=est.y,
            z=est.z,
            yaw_rad=est.yaw_rad,
            vx=est.vx,
            vy=est.vy,
            vz=est.vz,
            position_sigma_m=est.position_sigma_m,
            yaw_sigma_rad=est.yaw_sigma_rad,
            localised=est.localised,
            markers=self._markers,
            last_marker_t=self._last_marker_t,
            link_ok=link_ok,
            navdata_age_s=age,
            mode=self._mode.value,
            setpoint=self._setpoint,
            controller=self._loop.stats() if self._loop is not None else None,
            state_bits=int(nav.state) if nav is not None else 0,
            command=self._last_cmd,
            battery_known=body is not None,
            estimator_disagreement=est.disagreement,
            estimator_reinits=self.ekf.stats.navdata_reinits,
            jog_limit=self._jog_limit if self._mode is VehicleMode.MANUAL else "",
            navdata_doubt=self._navdata_doubt,
            gps_age_s=None if self._last_gps_t is None else max(0.0, now - self._last_gps_t),
            temperature_c=self._temperature_c,
        )

    def overlay(self, lines: tuple[str, ...] = ()) -> np.ndarray | None:
        """The latest camera frame with the tracking overlay, or None before the first frame."""
        frame = self._last_frame
        if frame is None:
            return None
        if self.camera is None:
            return frame
        s = self.snapshot()
        status = (
            f"{self.name} {s.ctrl_state} bat {s.battery_pct:.0f}%",
            f"x {s.x:.2f} y {s.y:.2f} z {s.z:.2f} yaw {s.yaw_deg:.0f}",
        )
        return draw_overlay(frame, self._last_result, self.camera, (*status, *lines))

    # ------------------------------------------------------------------ real time
    async def start(
        self,
        driver: Any,
        *,
        control_period_s: float = 0.01,
        least_frame_delay_s: float = 0.0,
        frame_latency_s: float = 0.05,
        own_process: bool = False,
        realtime_priority: int = 0,
    ) -> None:
        """Fly in real time with the asyncio ``ARDroneDriver`` ``driver`` (already started).

        Chains ``driver.on_event`` to :meth:`on_driver_event`, polls ``driver.latest_frame``
        (100 Hz) into the perception worker thread and starts the 100 Hz control thread. Each
        frame is stamped with its capture time (the EKF fuses it then): its PaVE timestamp
        mapped to this clock by :class:`FrameClock`, less ``least_frame_delay_s`` (the least
        capture-to-decode delay, which the mapping cannot see: about 6 ms on the simulator,
        ``bench/frame_stamps.py``); a driver without timestamps gets "seen − ``frame_latency_s``".
        ``own_process``: this process is the drone's alone (a vehicle process), so the control
        thread may hold the GIL while it spins to its deadline, and video decodes wait for room
        between its ticks (:meth:`ControlLoop.wait_for_room`); ``realtime_priority``: the
        SCHED_FIFO priority it asks for (0: normal scheduling). See drone/control/loop.py.
        """
        self.commander = driver
        self._driver = driver
        previous = getattr(driver, "on_event", None)

        def on_event(event: Any) -> None:
            self.on_driver_event(event)
            if previous is not None:
                previous(event)

        driver.on_event = on_event
        proto = getattr(driver, "protocol", None)
        if proto is not None and getattr(proto, "handshake_done", False):
            self.configure_drone()  # the handshake finished before this hook was in place
        if self.localiser is not None:
            self._worker = PerceptionWorker(
                self.localiser, self._worker_result, self._perception_context
            )
            self._worker.start()
        self._frame_task = asyncio.create_task(
            self._frame_pump(driver, least_frame_delay_s, frame_latency_s),
            name=f"{self.name}-frames",
        )
        self._loop = ControlLoop(
            self.control_step,
            period_s=control_period_s,
            on_stall=self._stalled,
            name=self.name,
            clock=self.clock.now,
            yield_while_spinning=not own_process,
            realtime_priority=realtime_priority,
        )
        self._loop.start()
        if own_process and hasattr(driver, "decode_gate"):
            driver.decode_gate = self._loop.wait_for_room

    async def _frame_pump(
        self, driver: Any, least_delay_s: float, latency_s: float, period_s: float = 0.01
    ) -> None:
        """Hand each newly decoded frame (``driver.latest_frame``) to perception."""
        seen = -1
        while True:
            n = getattr(driver, "frames_decoded", 0)
            frame = getattr(driver, "latest_frame", None)
            if n != seen and frame is not None:
                seen = n
                now = self.clock.now()
                ms = getattr(driver, "latest_frame_ms", None)
                if isinstance(ms, int):
                    stamp = self.frame_clock.stamp(ms, now) - least_delay_s
                else:
                    stamp = now - latency_s
                self.on_frame(frame, stamp)
            await asyncio.sleep(period_s)

    def _worker_result(self, result: FrameResult) -> None:
        self._on_result(result)

    def _stalled(self) -> None:
        if self.commander is not None:
            self.commander.hover()

    async def stop(self, *, land: bool = True) -> None:
        """Leave the drone safe (land, or hover with ``land=False``) and stop the threads."""
        if self.commander is not None:
            if land:
                self.land()
            else:
                self.hover()
        if self._frame_task is not None:
            self._frame_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._frame_task
            self._frame_task = None
        if self._loop is not None:
            self._loop.stop()
            await asyncio.sleep(0.1)  # let the driver put the land/hover on the wire
        if self._worker is not None:
            self._worker.stop()
            self._worker = None


@dataclass(frozen=True)
class _Extrapolated:
    """The estimate carried forward to ``now`` with its velocity (navdata is 15 Hz, control 100)."""

    est: Estimate
    now: float

    @property
    def _dt(self) -> float:
        return min(max(self.now - self.est.t, 0.0), 0.1)

    @property
    def x(self) -> float:
        return self.est.x + self.est.vx * self._dt

    @property
    def y(self) -> float:
        return self.est.y + self.est.vy * self._dt

    @property
    def z(self) -> float:
        return self.est.z + self.est.vz * self._dt

    @property
    def yaw_rad(self) -> float:
        return self.est.yaw_rad

    @property
    def vx(self) -> float:
        return self.est.vx

    @property
    def vy(self) -> float:
        return self.est.vy

    @property
    def vz(self) -> float:
        return self.est.vz
