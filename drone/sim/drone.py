"""``SimDrone``: the sans-I/O simulated AR.Drone 2.0 — AT bytes in, navdata bytes out.

It behaves as the drone does on the wire (Developer Guide SDK 2.0 §6–§7):

* AT commands (``receive_at``): sequence numbers must increase, seq 1 resets the counter (§6.1);
  ``AT*REF`` take-off bit is level-triggered, the emergency bit toggles EMERGENCY on a rising edge;
  ``AT*PCMD``/``PCMD_MAG`` set the onboard controller's targets; ``AT*CONFIG`` writes a key and
  raises the command-ACK state bit, ``AT*CTRL=5`` clears it; ``AT*COMWDG`` clears the COM-watchdog
  bit; garbage datagrams are ignored (counted in ``rejected_at``).
* the 2-second command timeout: with no AT command for 2 s the drone hovers and sets COM_LOST and
  COM_WATCHDOG (§7.1.2 state bits 13 and 30).
* navdata (``receive_navdata_request`` then ``navdata_due``): bootstrap packets (state bit 11, no
  options) until ``general:navdata_demo`` is set; then demo + checksum at 15 Hz, or at 200 Hz when
  ``navdata_demo`` is FALSE; the GPS option (tag 27) only when ``general:navdata_options`` asks for
  bit 27 and the world has a GPS origin; the raw-pressure option (tag 21) only when it asks for
  bit 21: the International Standard Atmosphere at the drone's height above sea level (the
  world's GPS elevation, or sea level indoors), with the barometer's noise.

Time: ``step(dt)`` advances the simulator clock ``time``; the ``now`` arguments are on that clock
(the socket server and ``InMemoryLink`` pass ``sim.time``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from drone.ardrone import at
from drone.ardrone.errors import ATParseError
from drone.ardrone.navdata import (
    TAG_GPS,
    TAG_PRESSURE_RAW,
    CtrlState,
    Demo,
    DroneState,
    Gps,
    Navdata,
    PressureRaw,
    encode_navdata,
)
from drone.sim.battery import FLIGHT_TIME_S, MAX_LEAK_PCT_S, Battery
from drone.sim.errors import FaultError, SimConfigError
from drone.sim.people import PersonPose, people_at
from drone.sim.physics import Body, FlightParams, Physics, as_box
from drone.sim.thermal import Thermal

DEFAULT_BOUNDS = (0.0, 8.0, 0.0, 6.0, 0.0, 3.0)  # the default indoor room, metres
COMMAND_TIMEOUT_S = 2.0  # Developer Guide §6.1: the drone treats 2 s without commands as lost
ALWAYS_ON = (
    DroneState.ATCODEC_THREAD_ON
    | DroneState.NAVDATA_THREAD_ON
    | DroneState.VIDEO_THREAD_ON
    | DroneState.ACQ_THREAD_ON
    | DroneState.VIDEO
    | DroneState.CAMERA
)


@dataclass(frozen=True)
class SimConfig:
    """Simulator knobs that are not the drone's own configuration."""

    seed: int = 1
    demo_rate_hz: float = 15.0  # navdata_demo TRUE (ARDroneLib: ~15 Hz)
    full_rate_hz: float = 200.0  # navdata_demo FALSE
    command_timeout_s: float = COMMAND_TIMEOUT_S
    altitude_noise_m: float = 0.004  # ultrasound
    velocity_noise_m_s: float = 0.015  # optical-flow speed estimate
    attitude_noise_rad: float = 0.001
    wind_bit_m_s: float = 4.0  # "too much wind" state bit above this air speed
    sea_level_pressure_pa: float = 101325.0  # ISA (ISO 2533)
    # None: ISA's 15 °C at sea level less 6.5 °C/km outdoors; a heated room's 21 °C indoors
    ground_temperature_c: float | None = None
    pressure_noise_pa: float = 10.0  # Parrot's AR.Drone 2.0 spec: pressure sensor ±10 Pa
    temperature_noise_c: float = 0.1
    # The GPS receiver (AR.Drone Flight Recorder): a new fix at this rate (u-blox receivers
    # compute 1-5 fixes a second), each with white noise of this 1-σ per horizontal axis. The
    # fixes are exact by default: the estimator's GPS update already assumes a real receiver's
    # σ (server/fleet/accuracy.py), and the lockstep experiments stay comparable.
    gps_rate_hz: float = 5.0
    gps_noise_m: float = 0.0
    gps_satellites: int = 9
    # a full battery's hover time, 100 % → 0 % (drone/sim/battery.py: the AR.Drone 2.0's 720 s)
    flight_time_s: float = FLIGHT_TIME_S


@dataclass(frozen=True)
class Truth:
    """Ground truth (map frame, REP 103) for tests, the REST ``/sim/{id}/truth`` and the camera."""

    t_s: float
    x: float
    y: float
    z: float
    yaw_rad: float
    vx: float
    vy: float
    vz: float
    roll: float  # rad, right wing down positive
    pitch: float  # rad, nose down positive
    battery_pct: float
    ctrl_state: CtrlState
    flying: bool
    emergency: bool
    temperature_c: float = 0.0  # what the barometer reads in the hull (drone/sim/thermal.py)


FAULT_KINDS = (
    "link_loss",
    "battery",
    "battery_drain",
    "wind_gust",
    "wind",
    "lost_markers",
    "payload",
    "clear",
)


class SimDrone:
    """The simulated drone. Not thread-safe: one owner calls it (server task or lockstep rig).

    Args:
        world: a ``drone.sim.world.World`` (uses ``bounds``, ``start``, ``gps_origin``, and its
            charging pads: ``pad_at``) or None.
        bounds: box ``(x_min, x_max, y_min, y_max, z_min, z_max)`` when there is no world.
        start: ``(x, y, yaw_rad)`` on the floor; default the world's start or the room's centre.
        params: onboard-controller limits and model constants.
        config: rates, timeouts, noise, seed.
        battery_pct: initial charge.
        seed: shorthand for ``config.seed`` (sensor noise, camera noise).

    Raises:
        SimConfigError: bad bounds or a start outside them.
    """

    def __init__(
        self,
        world: Any | None = None,
        *,
        bounds: Any | None = None,
        start: tuple[float, float, float] | None = None,
        params: FlightParams | None = None,
        config: SimConfig | None = None,
        battery_pct: float = 100.0,
        seed: int | None = None,
    ) -> None:
        self.world = world
        self.config = config or SimConfig()
        if seed is not None:
            self.config = replace(self.config, seed=seed)
        box = as_box(bounds if bounds is not None else getattr(world, "bounds", DEFAULT_BOUNDS))
        if start is None:
            ws = getattr(world, "start", None)
            if ws is not None:
                start = (float(ws.x), float(ws.y), float(ws.yaw_rad))
            else:
                start = ((box[0] + box[1]) / 2, (box[2] + box[3]) / 2, 0.0)
        x, y, yaw = start
        if not (box[0] <= x <= box[1] and box[2] <= y <= box[3]):
            raise SimConfigError(f"start {start} lies outside the bounds {box}")
        self.physics = Physics(
            bounds=box,
            params=params or FlightParams(),
            battery=Battery(pct=battery_pct, flight_time_s=self.config.flight_time_s),
            body=Body(x=x, y=y, z=box[4], yaw_rad=yaw),
        )
        self.thermal = Thermal()
        self.gps_origin = getattr(world, "gps_origin", None)
        self.rng = np.random.default_rng(self.config.seed)
        # its own stream: asking for the barometer does not change the other sensors' noise
        self._baro_rng = np.random.default_rng([self.config.seed, TAG_PRESSURE_RAW])
        self._gps_rng = np.random.default_rng([self.config.seed, TAG_GPS])
        self._gps_fix: Gps | None = None  # the receiver's last fix, held until the next one
        self._gps_next_t = 0.0  # when the receiver has its next fix (a fixed grid of epochs)
        self.time = 0.0
        self.settings: dict[str, str] = {}
        self.rejected_at = 0  # malformed AT datagrams ignored
        self.commands_accepted = 0
        self.navdata_sequence = 0
        self.frames = 0
        self._last_seq = 0
        self._last_at_time = -math.inf
        self._pad: Any | None = None  # the charging pad it landed on (``_charge``)
        self._ref_emergency = False
        self._ack = False
        self._com_watchdog = True  # raised until the client's first AT*COMWDG, as on boot
        self._streaming = False
        self._demo: bool | None = None  # None = bootstrap
        self._navdata_options = 0
        self._next_nav = 0.0
        self._link_down_until = -math.inf
        self._markers_lost_until = -math.inf
        self._renderer: Any | None = None
        self._renderer_no_markers: Any | None = None

    # ---------------------------------------------------------------- wire input
    @property
    def link_down(self) -> bool:
        """True while an injected ``link_loss`` fault drops every datagram."""
        return self.time < self._link_down_until

    @property
    def markers_lost(self) -> bool:
        """True while an injected ``lost_markers`` fault hides every marker from the camera."""
        return self.time < self._markers_lost_until

    def receive_at(self, data: bytes, now: float) -> None:
        """Feed one AT datagram (UDP 5556). Malformed datagrams are ignored (``rejected_at``)."""
        if self.link_down:
            return
        try:
            packets = at.parse_at(data)
        except ATParseError:
            self.rejected_at += 1
            return
        for packet in packets:
            if packet.seq == 1:
                self._last_seq = 0  # §6.1: sequence 1 resets the counter
            if packet.seq <= self._last_seq:
                continue
            self._last_seq = packet.seq
            self._last_at_time = now
            self.commands_accepted += 1
            self._apply(packet.command)

    def _apply(self, cmd: at.ParsedCommand) -> None:
        ph = self.physics
        match cmd:
            case at.Ref():
                rising = cmd.emergency_bit and not self._ref_emergency
                self._ref_emergency = cmd.emergency_bit
                if rising:
                    if ph.emergency:
                        ph.reset_emergency()
                    else:
                        ph.cut_motors()
                    return
                if cmd.takeoff_bit and ph.ctrl is CtrlState.LANDED:
                    ph.takeoff()
                elif not cmd.takeoff_bit and ph.flying:
                    ph.land()
            case at.Pcmd() | at.PcmdMag():
                ph.command(cmd.roll, cmd.pitch, cmd.gaz, cmd.yaw, cmd.progressive)
            case at.Config():
                self._configure(cmd.key, cmd.value)
                self._ack = True
            case at.Ctrl():
                if cmd.mode == at.CTRL_ACK:
                    self._ack = False
            case at.Comwdg():
                self._com_watchdog = False
            case _:
                pass  # FTRIM, CALIB, LED, ANIM, CONFIG_IDS, unknown: accepted, no effect here

    def _configure(self, key: str, value: str) -> None:
        """Store a config key; apply the ones the simulator models (ARDroneLib config_keys.h)."""
        self.settings[key] = value
        p = self.physics.params
        try:
            if key == "general:navdata_demo":
                self._demo = value.upper() == "TRUE"
                self._next_nav = min(self._next_nav, self.time)  # new rate from now on
            elif key == "general:navdata_options":
                self._navdata_options = int(value, 0)
            elif key == "control:euler_angle_max":  # radians
                p = _replace(p, euler_angle_max_rad=min(max(float(value), 0.0), math.radians(30)))
            elif key == "control:control_vz_max":  # mm/s
                p = _replace(p, control_vz_max_m_s=min(max(float(value), 200.0), 2000.0) / 1000)
            elif key == "control:control_yaw":  # rad/s
                p = _replace(p, control_yaw_rad_s=min(max(float(value), 0.7), 6.11))
            elif key == "control:outdoor":  # outdoor flight limits (config_keys.h *_outdoor)
                outdoor = value.upper() == "TRUE"
                p = _replace(
                    p,
                    euler_angle_max_rad=math.radians(20.0 if outdoor else 12.0),
                    control_vz_max_m_s=1.0 if outdoor else 0.7,
                    control_yaw_rad_s=math.radians(200.0 if outdoor else 100.0),
                )
            elif key == "control:altitude_max":  # mm
                p = _replace(p, altitude_max_m=min(max(float(value), 500.0), 100000.0) / 1000)
        except ValueError:
            return  # the drone ignores values it cannot read
        self.physics.params = p

    def receive_navdata_request(self, data: bytes, now: float) -> None:
        """A datagram on UDP 5554 from a client: start (or keep) streaming navdata to it."""
        if self.link_down:
            return
        if not self._streaming:
            self._streaming = True
            self._next_nav = now

    # ---------------------------------------------------------------- time
    def step(self, dt: float) -> None:
        """Advance the simulation by ``dt`` seconds (physics, battery, command watchdog).

        Raises:
            SimConfigError: ``dt`` is negative or not finite.
        """
        if not (math.isfinite(dt) and dt >= 0):
            raise SimConfigError(f"dt must be a finite non-negative number, got {dt!r}")
        self.time += dt
        if self.command_lost:
            self.physics.hover()
            self._com_watchdog = True
        flew = self.physics.motors_on
        self.physics.step(dt)
        self.thermal.step(dt, self.physics.battery.load, self.physics.motors_on)
        self._charge(dt, flew)

    def _charge(self, dt: float, flew: bool) -> None:
        """Charging: a drone that lands (its motors stop) on a charging pad of the world charges
        there at the pad's rate until it starts its motors again. A drone that has not landed
        on the pad since the simulator started, or since a battery fault set its charge, does
        not: the charge a fault sets is what the drone has."""
        ph = self.physics
        if ph.motors_on:
            self._pad = None
            return
        pad_at = getattr(self.world, "pad_at", None)
        if flew and pad_at is not None:  # it has just landed (or cut its motors) here
            pad = pad_at(ph.body.x, ph.body.y)
            self._pad = pad if pad is not None and pad.charge_pct_s > 0.0 else None
        if self._pad is not None:
            ph.battery.charge(self._pad.charge_pct_s * dt)

    def people(self) -> tuple[PersonPose, ...]:
        """Where the world's people are now (drone/sim/people.py): what a person tracker
        would tell the drone's supervisor."""
        return people_at(self.world, self.time)

    @property
    def charging(self) -> bool:
        """On a charging pad, charging (or full)."""
        return self._pad is not None

    @property
    def command_lost(self) -> bool:
        """No AT command for ``command_timeout_s``: the drone hovers on its own."""
        return self.time - self._last_at_time > self.config.command_timeout_s

    # ---------------------------------------------------------------- wire output
    @property
    def navdata_rate_hz(self) -> float:
        return self.config.full_rate_hz if self._demo is False else self.config.demo_rate_hz

    def navdata_due(self, now: float) -> bytes | None:
        """The next navdata packet if one is due at ``now`` (at most one per call), else None."""
        if not self._streaming or now < self._next_nav:
            return None
        period = 1.0 / self.navdata_rate_hz
        self._next_nav += period
        if self._next_nav <= now:
            self._next_nav = now + period
        if self.link_down:
            return None
        return encode_navdata(self.navdata())

    def state_bits(self) -> DroneState:
        ph = self.physics
        s = ALWAYS_ON
        if ph.flying:
            s |= DroneState.FLY | DroneState.ALTITUDE
        if self._demo is None:
            s |= DroneState.NAVDATA_BOOTSTRAP
        elif self._demo:
            s |= DroneState.NAVDATA_DEMO
        if self._ack:
            s |= DroneState.COMMAND
        if ph.battery.low:
            s |= DroneState.VBAT_LOW
        if ph.emergency:
            s |= DroneState.EMERGENCY
        if self.command_lost:
            s |= DroneState.COM_LOST
        if self._com_watchdog:
            s |= DroneState.COM_WATCHDOG
        wx, wy = ph.air()
        if math.hypot(wx, wy) > self.config.wind_bit_m_s:
            s |= DroneState.WIND
        return s

    def navdata(self) -> Navdata:
        """Build the current packet (advances the navdata sequence number)."""
        self.navdata_sequence += 1
        state = self.state_bits()
        if self._demo is None:
            return Navdata(state=state, sequence=self.navdata_sequence)
        return Navdata(
            state=state,
            sequence=self.navdata_sequence,
            demo=self._demo_option(),
            gps=self._gps_option() if self._navdata_options & (1 << TAG_GPS) else None,
            pressure=(
                self._pressure_option() if self._navdata_options & (1 << TAG_PRESSURE_RAW) else None
            ),
        )

    def _demo_option(self) -> Demo:
        ph, b, c, rng = self.physics, self.physics.body, self.config, self.rng
        fwd, left = b.body_velocity()
        n_att = rng.normal(0.0, c.attitude_noise_rad, 3)
        n_vel = rng.normal(0.0, c.velocity_noise_m_s, 3)
        n_alt = rng.normal(0.0, c.altitude_noise_m)
        airborne = ph.altitude_m > 0.0
        alt_mm = round((ph.altitude_m + n_alt) * 1000.0) if airborne else 0
        moving = ph.flying or ph.emergency
        psi = -math.degrees(math.remainder(b.yaw_rad + n_att[2], math.tau)) * 1000.0
        major = CtrlState.DEFAULT if ph.emergency else ph.ctrl
        return Demo(
            ctrl_state=int(major) << 16,
            battery_pct=round(ph.battery.reading_pct),
            theta_mdeg=-math.degrees(b.pitch_rad + n_att[0]) * 1000.0,
            phi_mdeg=math.degrees(b.roll_rad + n_att[1]) * 1000.0,
            psi_mdeg=psi,
            altitude_mm=max(0, alt_mm),
            vx_mm_s=(fwd + n_vel[0]) * 1000.0 if moving else 0.0,
            vy_mm_s=-(left + n_vel[1]) * 1000.0 if moving else 0.0,  # drone: right positive
            vz_mm_s=-(b.vz + n_vel[2]) * 1000.0 if moving else 0.0,  # drone: down positive
            num_frames=self.frames,
        )

    def _pressure_option(self) -> PressureRaw:
        """ISA barometric formula p = p0·(1 − L·h/T0)^(g·M/(R·L)) at the drone's height above
        sea level (ISO 2533 troposphere: L 0.0065 K/m, T0 288.15 K, exponent 5.25588)."""
        c, rng = self.config, self._baro_rng
        h = self._height_amsl_m()
        p = c.sea_level_pressure_pa * (1.0 - 2.25577e-5 * h) ** 5.25588
        p += rng.normal(0.0, c.pressure_noise_pa)
        # the hull's air: the outside air warmed by the motors (drone/sim/thermal.py)
        temp = self.air_temperature_c() + self.thermal.rise_c
        temp += rng.normal(0.0, c.temperature_noise_c)
        return PressureRaw(up=0, ut=0, temperature_dc=round(temp * 10.0), pressure_pa=round(p))

    def _height_amsl_m(self) -> float:
        elevation = self.gps_origin.alt_m if self.gps_origin is not None else 0.0
        return float(elevation + self.physics.body.z)

    def air_temperature_c(self) -> float:
        """The outside air: the configured ground temperature, a heated room's 21 °C indoors,
        else ISA's 15 °C at sea level less 6.5 °C/km (ISO 2533)."""
        c = self.config
        if c.ground_temperature_c is not None:
            return c.ground_temperature_c
        if self.world is not None and getattr(self.world, "indoor", False):
            return 21.0
        return 15.0 - 0.0065 * self._height_amsl_m()

    def _gps_option(self) -> Gps | None:
        """The receiver's latest fix: a new one every ``1 / gps_rate_hz`` s of simulated time
        (the option repeats it between fixes, as the drone does), at the true position plus
        the configured noise; ground speed and course from the true velocity."""
        o = self.gps_origin
        if o is None:
            return None
        c = self.config
        if self._gps_fix is not None and self.time < self._gps_next_t:
            return self._gps_fix
        import pymap3d  # only worlds with a GPS origin need it

        b, rng = self.physics.body, self._gps_rng
        e, n = b.x + rng.normal(0.0, c.gps_noise_m), b.y + rng.normal(0.0, c.gps_noise_m)
        u = b.z + rng.normal(0.0, 1.5 * c.gps_noise_m)  # vertical error ~1.5× horizontal
        lat, lon, alt = pymap3d.enu2geodetic(e, n, u, o.lat_deg, o.lon_deg, o.alt_m)
        # Dilutions of a good open-sky geometry; accuracy estimates from the configured noise.
        hdop, vdop = 0.9, 1.4
        sats = max(0, min(c.gps_satellites, 12))
        cn0 = 38.0 + 0.5 * sats  # dB-Hz, a clear sky's strong signals
        period = 1.0 / c.gps_rate_hz
        self._gps_next_t = (math.floor(self.time / period) + 1) * period
        self._gps_fix = Gps(
            float(lat),
            float(lon),
            float(alt),
            hdop=hdop,
            data_available=1,
            vdop=vdop,
            pdop=math.hypot(hdop, vdop),
            speed_m_s=math.hypot(b.vx, b.vy),
            last_frame_timestamp=int(self.time * 1000.0) & 0xFFFFFFFF,
            degree=math.degrees(math.atan2(b.vx, b.vy)) % 360.0,  # clockwise from north
            ehpe_m=math.sqrt(2.0) * c.gps_noise_m,
            ehve_m=1.5 * c.gps_noise_m,
            c_n0=cn0,
            nbsat=sats,
            channels=tuple((k + 1, round(cn0) - k % 4) for k in range(sats)),
            is_gps_plugged=1,
        )
        return self._gps_fix

    # ---------------------------------------------------------------- truth and faults
    @property
    def truth(self) -> Truth:
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
            flying=ph.flying,
            emergency=ph.emergency,
            temperature_c=self.air_temperature_c() + self.thermal.rise_c,
        )

    def inject_fault(self, kind: str, **params: float) -> None:
        """Inject a fault (``POST /sim/{id}/fault``, tests, the patrol rig).

        Kinds and parameters (aliases in brackets, as the REST body names them):
            ``link_loss(duration_s)``: drop every datagram both ways for that long.
            ``battery(pct [battery_pct])``: set the charge to ``pct`` (0..100) at once.
            ``battery_drain(pct_s [drain_pct_s])``: the pack leaks this much more per second
            (0..``MAX_LEAK_PCT_S``; 0 ends it).
            ``wind_gust(vx, vy, duration_s)``: extra wind in m/s (map frame) for that long.
            ``wind(vx [wind_x], vy [wind_y])``: steady wind in m/s (map frame); with
            ``duration_s`` it is a gust instead.
            ``lost_markers(duration_s)``: the camera sees no marker for that long (covered,
            glare), so the estimator runs on dead reckoning.
            ``payload(kg)``: carry ``kg`` (0..0.25; 0 removes it): the motors draw more and
            heat the hull more (drone/sim/thermal.py); the flight itself is unchanged.
            ``clear()``: end link loss, wind, gusts, the leak and lost markers (the battery
            keeps its charge).

        Raises:
            FaultError: unknown kind, missing/extra parameter, or a value out of range.
        """
        aliases = {"battery_pct": "pct", "drain_pct_s": "pct_s", "wind_x": "vx", "wind_y": "vy"}
        params = {aliases.get(k, k): v for k, v in params.items()}
        if kind == "wind" and "duration_s" in params:
            kind = "wind_gust"
        required = {
            "link_loss": {"duration_s"},
            "battery": {"pct"},
            "battery_drain": {"pct_s"},
            "wind_gust": {"vx", "vy", "duration_s"},
            "wind": {"vx", "vy"},
            "lost_markers": {"duration_s"},
            "payload": {"kg"},
            "clear": set(),
        }
        if kind not in required:
            raise FaultError(f"unknown fault kind {kind!r}; expected one of {FAULT_KINDS}")
        if set(params) != required[kind]:
            raise FaultError(f"fault {kind!r} takes {sorted(required[kind])}, got {sorted(params)}")
        try:
            vals = {k: float(v) for k, v in params.items()}
        except (TypeError, ValueError) as exc:
            raise FaultError(f"fault {kind!r} parameters must be numbers: {params}") from exc
        if not all(math.isfinite(v) for v in vals.values()):
            raise FaultError(f"fault {kind!r} parameters must be finite: {params}")
        if vals.get("duration_s", 0.0) < 0:
            raise FaultError("duration_s must be >= 0")
        if kind == "link_loss":
            self._link_down_until = self.time + vals["duration_s"]
        elif kind == "battery":
            if not 0.0 <= vals["pct"] <= 100.0:
                raise FaultError(f"battery pct must be in 0..100, got {vals['pct']}")
            self.physics.battery.drain_to(vals["pct"])
            self._pad = None  # the charge the fault sets stays until the next landing
        elif kind == "battery_drain":
            if not 0.0 <= vals["pct_s"] <= MAX_LEAK_PCT_S:
                raise FaultError(f"battery drain must be in 0..{MAX_LEAK_PCT_S} %/s")
            self.physics.battery.leak(vals["pct_s"])
        elif kind == "lost_markers":
            self._markers_lost_until = self.time + vals["duration_s"]
        elif kind == "wind_gust":
            self.physics.gust(vals["vx"], vals["vy"], vals["duration_s"])
        elif kind == "wind":
            self.physics.wind = (vals["vx"], vals["vy"])
        elif kind == "payload":
            try:
                self.thermal.carry(vals["kg"])
            except SimConfigError as exc:
                raise FaultError(str(exc)) from exc
        else:
            self._link_down_until = -math.inf
            self._markers_lost_until = -math.inf
            self.physics.wind = (0.0, 0.0)
            self.physics.clear_gusts()
            self.physics.battery.leak(0.0)

    # ---------------------------------------------------------------- camera
    def render_frame(self, truth: Truth | None = None) -> np.ndarray | None:
        """The front camera image (640×360 BGR) at ``truth`` (default: now), None without a world.

        Uses ``drone.sim.camera.Renderer`` (seeded like the simulator); counts ``frames`` for the
        demo option's ``num_frames``. Passing a ``truth`` snapshot lets a worker thread render
        while the owner keeps stepping. While markers are lost (fault) the scene is drawn
        without them.
        """
        if self.world is None:
            return None
        from drone.sim.camera import Renderer

        if self.markers_lost:
            if self._renderer_no_markers is None:
                bare = replace(self.world, markers=())
                self._renderer_no_markers = Renderer(bare, seed=self.config.seed)
            renderer = self._renderer_no_markers
        else:
            if self._renderer is None:
                self._renderer = Renderer(self.world, seed=self.config.seed)
            renderer = self._renderer
        pose = self.truth if truth is None else truth
        img: np.ndarray = renderer.render(pose, frame=self.frames)
        self.frames += 1
        return img


def _replace(p: FlightParams, **changes: float) -> FlightParams:
    return replace(p, **changes)
