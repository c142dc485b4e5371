"""``MavlinkVehicle``: a PX4/ArduPilot drone behind the same interface as ``drone.vehicle.Vehicle``.

The task manager, the dialog, the fleet and the graph node call the same methods on both
(``takeoff land emergency reset hover jog set_setpoint snapshot add_jog_listener clock``); the
difference is who closes the position loop. On the AR.Drone the console does (EKF + 100 Hz PID);
here the autopilot does, and the console only sends targets (DESIGN §3 "Vehicles"):

* ``takeoff`` → arm, then NAV_TAKEOFF (MIS_TAKEOFF_ALT above home, 2.5 m by default);
* ``set_setpoint`` (map frame) → SET_POSITION_TARGET_LOCAL_NED position targets streamed in
  OFFBOARD (PX4) / GUIDED (ArduPilot); a yaw-rate setpoint (tag search) streams a yaw rate;
* ``jog`` (``/cmd_vel`` fractions, ardrone_autonomy semantics) → a body-frame velocity turned into
  local NED, streamed while held (``JOG_SPEED_M_S`` per unit), zero velocity on release, then
  hold;
* ``hover`` → hold mode (PX4 AUTO.LOITER / ArduCopter LOITER); ``land`` → land mode;
  ``return_home`` → RTL; ``emergency`` → motors off now (force disarm, as MAVSDK's ``kill``);
  ``reset`` → nothing to reset on an autopilot beyond disarming on the ground.

The map frame is the world's local ENU at its GPS origin; positions come from
GLOBAL_POSITION_INT, and targets go out relative to the local NED origin found from
HOME_POSITION (its geodetic point and its local coordinates).

Outcomes of commands (accepted, denied with the vehicle's reason, no answer), STATUSTEXT and link
loss are kept as ``notices`` (``drain_notices()``): the graph node turns them into console
replies (alerts for denials and failsafes).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drone.control.clock import Clock, MonotonicClock
from drone.control.pid import Setpoint
from drone.mavlink.codec import mav
from drone.mavlink.gcs.events import (
    CommandResult,
    LinkLost,
    LinkRestored,
    MavlinkTelemetry,
    MissionItemReached,
    MissionResult,
    OtherVehicle,
    StatusText,
    VehicleFound,
)
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.geo import Origin, enu_to_ned, ned_to_enu, yaw_enu_to_ned, yaw_ned_to_enu
from drone.vehicle import VehicleMode, VehicleSnapshot

log = logging.getLogger(__name__)

JOG_SPEED_M_S = 3.0  # horizontal speed at full stick
JOG_CLIMB_M_S = 1.0
JOG_YAW_RATE_RAD_S = math.radians(45.0)
TAKEOFF_ALT_M = 2.5  # PX4 MIS_TAKEOFF_ALT default
OFFBOARD_ASK_S = 2.0  # > the 1 s heartbeat period that confirms a mode change


@dataclass(frozen=True)
class Notice:
    """Something the operator should hear: ``level`` info, warn or alert."""

    level: str
    text: str


class MavlinkVehicle:
    """See the module docstring.

    Args:
        name: ``uav1``…
        world: the map (``drone.sim.world.World``); its ``gps_origin`` anchors the map frame.
        protocol: the link's :class:`GcsProtocol` (lockstep or under a ``MavlinkDriver``).
        clock: time source (virtual in lockstep).
        link_timeout_s: kept for symmetry with ``Vehicle``; the protocol's watchdog decides.
    """

    # The autopilot holds position by itself (PX4 AUTO.LOITER, ArduCopter LOITER), so a hover
    # is its hold mode rather than a stream of position targets: it keeps holding if this
    # process stops, with no offboard-loss failsafe in between (server.tasks.flight.HoverTask).
    holds_position = True

    def __init__(
        self,
        name: str,
        world: Any,
        protocol: GcsProtocol,
        *,
        clock: Clock | None = None,
        takeoff_alt_m: float = TAKEOFF_ALT_M,
    ) -> None:
        self.name = name
        self.world = world
        self.protocol = protocol
        self.clock: Clock = clock or MonotonicClock()
        self.takeoff_alt_m = takeoff_alt_m
        go = getattr(world, "gps_origin", None)
        self.origin: Origin | None = Origin(go.lat_deg, go.lon_deg, go.alt_m) if go else None
        self.commander = None  # no AR.Drone driver config (server.fleet.ltm looks for one)
        self._lock = threading.RLock()
        self._mode = VehicleMode.IDLE
        self._setpoint: Setpoint | None = None
        self._jogging = False
        self._jog_listeners: list[Callable[[], None]] = []
        self._telemetry_listeners: list[Callable[[MavlinkTelemetry, float], None]] = []
        self._notices: deque[Notice] = deque(maxlen=64)
        self._driver: Any | None = None
        self._pending: dict[int, str] = {}  # token -> what the operator asked
        self._link_text: str | None = None
        self._last_t: float | None = None
        self._offboard_asked_t = -math.inf
        self.frames_seen = 0

    # ------------------------------------------------------------------ plumbing
    def _flush(self) -> None:
        if self._driver is not None:
            self._driver.flush()

    def _now(self) -> float:
        return self.clock.now()

    def _track(self, token: int, what: str) -> None:
        self._pending[token] = what

    def drain_notices(self) -> list[Notice]:
        with self._lock:
            out = list(self._notices)
            self._notices.clear()
        return out

    def add_jog_listener(self, cb: Callable[[], None]) -> None:
        self._jog_listeners.append(cb)

    def add_telemetry_listener(self, cb: Callable[[MavlinkTelemetry, float], None]) -> None:
        """``cb(telemetry, now)`` after each message batch from the vehicle."""
        self._telemetry_listeners.append(cb)

    def marker_ids(self) -> tuple[int, ...]:
        return ()

    # ------------------------------------------------------------------ commands
    def takeoff(self) -> None:
        """Arm and take off to ``takeoff_alt_m`` above home."""
        with self._lock:
            self._mode = VehicleMode.IDLE
            self._setpoint = None
            self.protocol.stop_setpoints(self._now())
            token = self.protocol.arm_and_takeoff(self.takeoff_alt_m, self._now())
            self._track(token, "take off")
        self._flush()

    def land(self) -> None:
        """Land here now (ahead of queued commands)."""
        with self._lock:
            self._mode = VehicleMode.LANDING
            self._setpoint = None
            self._jogging = False
            self.protocol._setpoint = None  # no setpoint may follow a land
            self._track(self.protocol.intent("land", self._now()), "land")
        self._flush()

    def return_home(self) -> None:
        """Return to launch (the autopilot's RTL: climb, fly home, land)."""
        with self._lock:
            self._mode = VehicleMode.AUTO
            self._setpoint = None
            self.protocol.stop_setpoints(self._now())
            self._track(self.protocol.intent("rtl", self._now()), "return home")
        self._flush()

    def emergency(self) -> None:
        """Motors off now (force disarm), ahead of anything queued."""
        with self._lock:
            self._mode = VehicleMode.EMERGENCY
            self._setpoint = None
            self._jogging = False
            self._track(self.protocol.kill(self._now()), "stop the motors")
        self._flush()

    def reset(self) -> None:
        """Leave EMERGENCY (the autopilot needs nothing more than a disarmed vehicle)."""
        with self._lock:
            self._mode = VehicleMode.IDLE

    def hover(self) -> None:
        """Hold position (hold/loiter mode); stops any setpoint stream."""
        with self._lock:
            if self._mode not in (VehicleMode.LANDING, VehicleMode.EMERGENCY):
                self._mode = VehicleMode.IDLE
            self._setpoint = None
            self._jogging = False
            self.protocol.stop_setpoints(self._now())
            t = self.protocol.telemetry
            if t.armed and t.landed_state not in ("ON_GROUND", "LANDING"):
                self._track(self.protocol.intent("hold", self._now()), "hold position")
        self._flush()

    def jog(self, linear_x: float, linear_y: float, linear_z: float, angular_z: float) -> None:
        """``/cmd_vel`` fractions → body velocity → local NED, streamed; zeros release it.

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
            now = self._now()
            if c == [0.0, 0.0, 0.0, 0.0]:
                was = self._jogging
                self._jogging = False
                self._mode = VehicleMode.IDLE
                if was:
                    self.protocol.stop_setpoints(now)
                    self._track(self.protocol.intent("hold", now), "hold position")
            else:
                yaw_ned = self.protocol.telemetry.heading_rad
                fwd, left = c[0] * JOG_SPEED_M_S, c[1] * JOG_SPEED_M_S
                # body FLU → NED: north = fwd·cos ψ − right·sin ψ, with right = −left
                vn = fwd * math.cos(yaw_ned) + left * math.sin(yaw_ned)
                ve = fwd * math.sin(yaw_ned) - left * math.cos(yaw_ned)
                vd = -c[2] * JOG_CLIMB_M_S
                rate = -c[3] * JOG_YAW_RATE_RAD_S  # CCW (left) positive → NED clockwise
                self.protocol.set_velocity(vn, ve, vd, rate, now)
                self._want_offboard(now, "fly manually")
                self._jogging = True
                self._mode = VehicleMode.MANUAL
            listeners = list(self._jog_listeners)
        self._flush()
        for cb in listeners:
            cb()

    def set_setpoint(self, setpoint: Setpoint | None) -> None:
        """Fly to ``setpoint`` (map frame) — the autopilot's position controller does the flying."""
        with self._lock:
            if self._mode in (VehicleMode.LANDING, VehicleMode.EMERGENCY):
                if setpoint is None:
                    self._setpoint = None
                return
            if setpoint is None:
                self._setpoint = None
                self._mode = VehicleMode.IDLE
                self.protocol.stop_setpoints(self._now())
                return
            local = self._map_to_local(setpoint.x, setpoint.y, setpoint.z)
            if local is None:
                self._notices.append(Notice("warn", "No home position yet: I can't fly there."))
                return
            now = self._now()
            self.protocol.set_position(
                *local,
                yaw_enu_to_ned(setpoint.yaw_rad),
                None if setpoint.yaw_rate_rad_s is None else -setpoint.yaw_rate_rad_s,
                now,
            )
            self._setpoint = setpoint
            self._jogging = False
            self._mode = VehicleMode.AUTO
            self._want_offboard(now, "fly to the target")
        self._flush()

    @property
    def setpoint(self) -> Setpoint | None:
        return self._setpoint

    def _want_offboard(self, now: float, what: str) -> None:
        """Ask for OFFBOARD/GUIDED unless the vehicle is in it, or was asked in the last 2 s (the
        heartbeat that shows the new mode comes at 1 Hz): never the same request twice."""
        if self.protocol.telemetry.mode in ("OFFBOARD", "GUIDED"):
            return
        if now - self._offboard_asked_t < OFFBOARD_ASK_S:
            return
        self._offboard_asked_t = now
        self._track(self.protocol.intent("offboard", now), what)

    # ------------------------------------------------------------------ frames
    def _local_origin_map(self) -> tuple[float, float, float] | None:
        """The local NED origin in the map frame (from HOME_POSITION)."""
        t = self.protocol.telemetry
        if t.home is None or t.home_local is None or self.origin is None:
            return None
        hx, hy, hz = self.origin.to_map(*t.home)
        e, n, u = ned_to_enu(*t.home_local)
        return hx - e, hy - n, hz - u

    def _map_to_local(self, x: float, y: float, z: float) -> tuple[float, float, float] | None:
        o = self._local_origin_map()
        if o is None:
            return None
        return enu_to_ned(x - o[0], y - o[1], z - o[2])

    def map_position(self) -> tuple[float, float, float] | None:
        """The vehicle's map position from its global position (None before the first fix)."""
        t = self.protocol.telemetry
        if self.origin is None or math.isnan(t.lat_deg):
            if t.local_ned is not None:
                o = self._local_origin_map() or (0.0, 0.0, 0.0)
                e, n, u = ned_to_enu(*t.local_ned)
                return o[0] + e, o[1] + n, o[2] + u
            return None
        return self.origin.to_map(t.lat_deg, t.lon_deg, t.alt_amsl_m)

    def geo(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        """Map → (lat, lon, alt AMSL); raises ``ValueError`` in a world without a GPS origin."""
        if self.origin is None:
            raise ValueError("this world has no GPS origin")
        return self.origin.to_geo(x, y, z)

    # ------------------------------------------------------------------ missions
    def upload_patrol(self, points: list[tuple[float, float, float]]) -> None:
        """Upload map-frame points as a mission (altitudes relative to home)."""
        home = self.protocol.telemetry.home
        base = self.origin.to_map(*home)[2] if home and self.origin else 0.0
        geo = []
        for x, y, z in points:
            lat, lon, _ = self.geo(x, y, z)
            geo.append((lat, lon, z - base))
        with self._lock:
            self.protocol.upload_mission(geo, self._now())
        self._flush()

    def start_mission(self) -> None:
        with self._lock:
            self._setpoint = None
            self._mode = VehicleMode.AUTO
            self.protocol.stop_setpoints(self._now())
            self._track(
                self.protocol.command(mav.MAV_CMD_MISSION_START, 0, 0, now=self._now()),
                "start the mission",
            )
        self._flush()

    # ------------------------------------------------------------------ events
    def on_event(self, event: Any) -> None:
        """A protocol event (from the driver or the lockstep link)."""
        now = self._now()
        with self._lock:
            if isinstance(event, CommandResult):
                what = self._pending.pop(event.token, None)
                if what is not None and not event.ok:
                    failed = event.cause if event.cause is not None else event
                    if failed.result == "NO_ANSWER":
                        text = f"The drone did not answer when I asked it to {what}."
                    else:
                        why = f": {failed.reason}" if failed.reason else ""
                        text = f"The drone refused to {what} ({failed.result.lower()}){why}."
                    self._notices.append(Notice("alert", text))
                    if what in ("fly to the target", "fly manually"):
                        self.protocol.stop_setpoints(now)
                        self._setpoint = None
                        self._mode = VehicleMode.IDLE
            elif isinstance(event, StatusText):
                level = (
                    "alert"
                    if event.severity <= mav.MAV_SEVERITY_CRITICAL
                    else ("warn" if event.severity <= mav.MAV_SEVERITY_WARNING else "info")
                )
                self._notices.append(Notice(level, f"{self.name}: {event.text}"))
                if self._mode is VehicleMode.AUTO and "offboard lost" in event.text.lower():
                    self._setpoint = None
                    self._mode = VehicleMode.IDLE
            elif isinstance(event, LinkLost):
                # the ANS link monitor says it (with this failsafe text), as for the AR.Drone
                self._link_text = event.failsafe
            elif isinstance(event, LinkRestored):
                pass
            elif isinstance(event, OtherVehicle):
                self._notices.append(
                    Notice(
                        "warn",
                        f"Another vehicle (system id {event.system_id}) is on "
                        f"{self.name}'s link; I ignore it.",
                    )
                )
            elif isinstance(event, VehicleFound):
                self._notices.append(Notice("info", f"{self.name}: {event.autopilot} connected."))
            elif isinstance(event, MissionResult):
                level = "info" if event.ok else "alert"
                self._notices.append(Notice(level, f"{self.name}: mission upload {event.detail}."))
            elif isinstance(event, MissionItemReached):
                pass
        self._last_t = now
        t = self.protocol.telemetry
        for cb in list(self._telemetry_listeners):
            cb(t, now)

    def poll(self) -> None:
        """Telemetry listeners after a batch of bytes with no event (the driver calls it)."""
        t = self.protocol.telemetry
        now = self._now()
        for cb in list(self._telemetry_listeners):
            cb(t, now)

    # ------------------------------------------------------------------ output
    def snapshot(self) -> VehicleSnapshot:
        now = self._now()
        t = self.protocol.telemetry
        # Before the first position, 0 with ``localised`` False (the fleet needs finite numbers).
        pos = self.map_position() or (0.0, 0.0, 0.0)
        known = self.map_position() is not None
        vx, vy, vz = ned_to_enu(t.vn, t.ve, t.vd)
        if t.landed_state == "ON_GROUND" or not t.armed:
            ctrl = "LANDED"
        elif t.landed_state == "TAKEOFF" or t.mode == "AUTO.TAKEOFF":
            ctrl = "TAKEOFF"
        elif t.landed_state == "LANDING":
            ctrl = "LANDING"
        else:
            ctrl = "FLYING" if math.hypot(vx, vy) > 0.3 else "HOVERING"
        emergency = t.system_status == mav.MAV_STATE_EMERGENCY or (
            self._mode is VehicleMode.EMERGENCY and not t.armed
        )
        if emergency:
            ctrl = "DEFAULT"
        with self._lock:
            mode = self._mode
            if mode is VehicleMode.LANDING and ctrl == "LANDED":
                mode = self._mode = VehicleMode.IDLE
        age = None if t.last_message_t is None else max(0.0, now - t.last_message_t)
        sigma = t.eph_m if math.isfinite(t.eph_m) else 5.0
        return VehicleSnapshot(
            name=self.name,
            t=now,
            ctrl_state=ctrl,
            flying=t.armed and ctrl not in ("LANDED", "DEFAULT"),
            emergency=emergency,
            battery_pct=t.battery_pct if math.isfinite(t.battery_pct) else 0.0,
            battery_known=math.isfinite(t.battery_pct),  # BATTERY_STATUS / SYS_STATUS came
            altitude_m=t.rel_alt_m if math.isfinite(t.rel_alt_m) else 0.0,
            x=pos[0],
            y=pos[1],
            z=pos[2],
            yaw_rad=yaw_ned_to_enu(t.heading_rad),
            vx=vx,
            vy=vy,
            vz=vz,
            position_sigma_m=sigma,
            yaw_sigma_rad=math.radians(2.0),
            localised=t.gps_fix >= 3 and known,
            markers=(),
            # A GPS fix is the absolute fix the task manager's marker search waits for.
            last_marker_t=t.last_message_t if t.gps_fix >= 3 else None,
            # linked once the vehicle's state is known (heartbeat and battery), as navdata is
            link_ok=self.protocol.connected and math.isfinite(t.battery_pct),
            navdata_age_s=age,
            mode=mode.value,
            setpoint=self._setpoint,
            controller=None,
            extra={
                "protocol": "mavlink",
                "autopilot": t.autopilot,
                "system_id": t.system_id,
                "flight_mode": t.mode,
                "armed": t.armed,
                "landed_state": t.landed_state,
                "gps_fix": t.gps_fix,
                "satellites": t.satellites,
                "lat": t.lat_deg,
                "lon": t.lon_deg,
                "alt_amsl_m": t.alt_amsl_m,
                "voltage_v": t.voltage_v,
                "home": list(t.home) if t.home else None,
                "failsafe": self._link_text or self.protocol.failsafe_text(),
            },
        )

    # ------------------------------------------------------------------ real time
    async def start(self, driver: Any, **_: Any) -> None:
        """Hook ``driver`` (a started ``MavlinkDriver`` on ``self.protocol``)."""
        self._driver = driver
        previous = driver.on_event

        def on_event(event: Any) -> None:
            if previous is not None:
                previous(event)
            self.on_event(event)

        driver.on_event = on_event

    async def stop(self, *, land: bool = True) -> None:
        """Land when flying (or hold when ``land`` is False), then let the commands go out."""
        snap = self.snapshot()
        if snap.flying:
            (self.land if land else self.hover)()
            with contextlib.suppress(Exception):
                await asyncio.sleep(0.1)
        self._driver = None
