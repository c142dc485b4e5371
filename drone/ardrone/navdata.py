"""Sans-I/O codec for AR.Drone 2.0 navdata (UDP 5554).

Packet layout (Developer Guide SDK 2.0 §7.1; ARDroneLib ``Soft/Common/navdata_common.h``), all
little-endian: ``u32 header 0x55667788, u32 drone state, u32 sequence, u32 vision flag``, then
option blocks ``u16 tag, u16 size (including these 4 bytes), payload``; the last option is the
checksum (tag 0xFFFF, size 8, u32 = sum of every preceding byte, ``navdata_compute_cks``).

Options decoded here: demo (tag 0, 148 bytes, ``navdata_demo_t``), raw pressure (tag 21,
18 bytes, ``navdata_pressure_raw_t``: i32 up, i16 ut, i32 Temperature_meas, i32 Pression_meas —
the barometer's compensated temperature in 0.1 °C and pressure in Pa, which ardrone_autonomy
copies into ``temp`` and ``pressure``), GPS (tag 27, 216 bytes, the
firmware 2.4 layout used by ardrone_autonomy's ``gps`` branch: float64 latitude, longitude,
elevation, hdop, u32 data_available, then the rest of ``navdata_gps_t``: see :class:`Gps`) and
the checksum. Unknown options are skipped
by their size and kept raw so that encode(decode(x)) == x.

Raw AR.Drone values (millidegrees, psi clockwise, vy right, vz down) stay inside this module;
:meth:`Navdata.to_body` converts them to REP 103 exactly as ardrone_autonomy does
(rotZ = −psi, vy = −vy, vz = −vz; docs/CONVENTIONS.md).
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass, field, fields
from typing import Any

from drone.ardrone.errors import (
    NavdataChecksumError,
    NavdataMagicError,
    NavdataOptionSizeError,
    NavdataTruncatedError,
)

NAVDATA_MAGIC = 0x55667788  # navdata_common.h NAVDATA_HEADER
TAG_DEMO = 0  # navdata_keys.h NAVDATA_DEMO_TAG
TAG_PRESSURE_RAW = 21  # navdata_keys.h NAVDATA_PRESSURE_RAW_TAG
TAG_GPS = 27  # ardrone_autonomy gps branch, firmware 2.4.x
TAG_CHECKSUM = 0xFFFF  # NAVDATA_CKS_TAG
DEMO_SIZE = 148  # sizeof(navdata_demo_t)
GPS_SIZE = 216
PRESSURE_SIZE = 18  # sizeof(navdata_pressure_raw_t), packed
CHECKSUM_SIZE = 8  # sizeof(navdata_cks_t)
NAVDATA_PORT = 5554

_HEADER = struct.Struct("<IIII")
_OPTION = struct.Struct("<HH")
# navdata_demo_t after tag/size: ctrl_state, vbat_flying_percentage, theta, phi, psi, altitude,
# vx, vy, vz, num_frames; then deprecated detection/drone camera fields (9+3 f32, 2 u32, 9+3 f32).
_DEMO = struct.Struct("<IIfffifffI")
_DEMO_PAD = DEMO_SIZE - _OPTION.size - _DEMO.size  # 104 bytes of deprecated camera fields
# navdata_gps_t after tag/size, in the field order of ardrone_autonomy's navdata_gps.msg with
# ARDroneLib's types (packed; bool_t is int32): 212 bytes, the option's 216 less tag and size.
_GPS = struct.Struct("<ddddIIIddddI10fddfIfffffI24BIIffI")
GPS_CHANNELS = 12  # navdata_gps_channel[12]: (satellite id, C/N0) of each receiver channel
_PRESSURE = struct.Struct("<ihii")  # up, ut, Temperature_meas, Pression_meas
assert _GPS.size == GPS_SIZE - _OPTION.size
_CKS = struct.Struct("<HHI")


class DroneState(enum.IntFlag):
    """The 32-bit drone state (ARDroneLib ``Soft/Common/config.h`` ARDRONE_*_MASK)."""

    FLY = 1 << 0  # flying
    VIDEO = 1 << 1  # video enabled
    VISION = 1 << 2  # vision enabled
    CONTROL = 1 << 3  # 0 euler-angle control, 1 angular-speed control
    ALTITUDE = 1 << 4  # altitude control active
    USER_FEEDBACK_START = 1 << 5  # start button state
    COMMAND = 1 << 6  # control command ACK
    CAMERA = 1 << 7  # camera ready
    TRAVELLING = 1 << 8
    USB = 1 << 9  # USB key ready
    NAVDATA_DEMO = 1 << 10  # demo mode (else all options)
    NAVDATA_BOOTSTRAP = 1 << 11  # no navdata options sent
    MOTORS = 1 << 12  # motors problem
    COM_LOST = 1 << 13  # communication lost
    SOFTWARE_FAULT = 1 << 14
    VBAT_LOW = 1 << 15  # battery too low to fly
    USER_EL = 1 << 16  # user emergency landing
    TIMER_ELAPSED = 1 << 17
    MAGNETO_NEEDS_CALIB = 1 << 18
    ANGLES_OUT_OF_RANGE = 1 << 19
    WIND = 1 << 20  # too much wind
    ULTRASOUND = 1 << 21  # ultrasonic sensor deaf
    CUTOUT = 1 << 22  # cutout system detected
    PIC_VERSION = 1 << 23
    ATCODEC_THREAD_ON = 1 << 24
    NAVDATA_THREAD_ON = 1 << 25
    VIDEO_THREAD_ON = 1 << 26
    ACQ_THREAD_ON = 1 << 27
    CTRL_WATCHDOG = 1 << 28  # control loop delay > 5 ms
    ADC_WATCHDOG = 1 << 29
    COM_WATCHDOG = 1 << 30  # communication problem: client should send AT*COMWDG
    EMERGENCY = 1 << 31


class CtrlState(enum.IntEnum):
    """Major control state, the high 16 bits of demo ``ctrl_state`` (control_states.h)."""

    DEFAULT = 0
    INIT = 1
    LANDED = 2
    FLYING = 3
    HOVERING = 4
    TEST = 5
    TAKEOFF = 6
    GOTOFIX = 7
    LANDING = 8
    LOOPING = 9


@dataclass(frozen=True)
class Demo:
    """The demo option, raw AR.Drone units (navdata_demo_t)."""

    ctrl_state: int = CtrlState.LANDED << 16  # major << 16 | minor
    battery_pct: int = 100
    theta_mdeg: float = 0.0  # pitch, nose up positive
    phi_mdeg: float = 0.0  # roll, right wing down positive
    psi_mdeg: float = 0.0  # yaw, clockwise positive, (-180000, 180000]
    altitude_mm: int = 0
    vx_mm_s: float = 0.0  # body forward
    vy_mm_s: float = 0.0  # body right
    vz_mm_s: float = 0.0  # down
    num_frames: int = 0

    @property
    def major(self) -> CtrlState | int:
        """Major control state (a :class:`CtrlState` when known, else the raw int)."""
        major = self.ctrl_state >> 16
        try:
            return CtrlState(major)
        except ValueError:
            return major

    @property
    def minor(self) -> int:
        return self.ctrl_state & 0xFFFF


@dataclass(frozen=True)
class Gps:
    """The firmware-2.4 GPS option (tag 27, ``navdata_gps_t``), field for field as
    ardrone_autonomy's ``navdata_gps`` message names them (snake case, units where they help).

    The fix first (position, dilutions, speed, course, accuracy estimates, satellites); the
    ``*_traj``, ``*_ref`` and PID terms are the firmware's own GPS flight controller's, zero
    unless it flies a GPS flight plan. ``channels``: (satellite id, C/N0 dB-Hz) per channel.
    """

    latitude_deg: float
    longitude_deg: float
    elevation_m: float
    hdop: float = 1.0
    data_available: int = 1
    zero_validated: int = 0
    wpt_validated: int = 0
    lat0_deg: float = 0.0
    long0_deg: float = 0.0
    lat_fused_deg: float = 0.0
    long_fused_deg: float = 0.0
    gps_state: int = 0
    x_traj: float = 0.0
    x_ref: float = 0.0
    y_traj: float = 0.0
    y_ref: float = 0.0
    theta_p: float = 0.0
    phi_p: float = 0.0
    theta_i: float = 0.0
    phi_i: float = 0.0
    theta_d: float = 0.0
    phi_d: float = 0.0
    vdop: float = 0.0
    pdop: float = 0.0
    speed_m_s: float = 0.0
    last_frame_timestamp: int = 0
    degree: float = 0.0  # course over ground, degrees clockwise from north
    degree_magnetic: float = 0.0
    ehpe_m: float = 0.0  # estimated horizontal position error
    ehve_m: float = 0.0  # estimated vertical position error
    c_n0: float = 0.0  # signal to noise ratio, mean of the four best satellites (dB-Hz)
    nbsat: int = 0  # satellites acquired
    channels: tuple[tuple[int, int], ...] = ()
    is_gps_plugged: int = 0
    ephemeris_status: int = 0
    vx_traj: float = 0.0
    vy_traj: float = 0.0
    firmware_status: int = 0

    def __post_init__(self) -> None:
        """Channels as the option holds them: 12, the unused ones (0, 0).

        Raises:
            ValueError: more than 12 channels.
        """
        if len(self.channels) > GPS_CHANNELS:
            raise ValueError(f"a GPS option has {GPS_CHANNELS} channels, got {len(self.channels)}")
        pad = ((0, 0),) * (GPS_CHANNELS - len(self.channels))
        object.__setattr__(self, "channels", tuple(tuple(c) for c in self.channels) + pad)

    def pack(self) -> bytes:
        """The option's payload (after tag and size)."""
        flat = [v for pair in self.channels for v in pair]
        vals = [getattr(self, f.name) for f in fields(self) if f.name != "channels"]
        head, tail = vals[:_GPS_CHANNELS_AT], vals[_GPS_CHANNELS_AT:]
        return _GPS.pack(*head, *flat, *tail)

    @classmethod
    def unpack(cls, data: bytes, offset: int) -> Gps:
        vals = _GPS.unpack_from(data, offset)
        at, end = _GPS_CHANNELS_AT, _GPS_CHANNELS_AT + 2 * GPS_CHANNELS
        chans = vals[at:end]
        pairs = tuple((chans[2 * i], chans[2 * i + 1]) for i in range(GPS_CHANNELS))
        names = [f.name for f in fields(cls) if f.name != "channels"]
        kw = dict(zip(names, vals[:at] + vals[end:], strict=True))
        return cls(**kw, channels=pairs)


_GPS_CHANNELS_AT = 32  # index of the first channel byte among the unpacked values


@dataclass(frozen=True)
class PressureRaw:
    """The barometer option (tag 21): raw ADC words and the compensated readings."""

    up: int  # uncompensated pressure (ADC word)
    ut: int  # uncompensated temperature (ADC word)
    temperature_dc: int  # Temperature_meas, 0.1 °C
    pressure_pa: int  # Pression_meas, Pa

    @property
    def temperature_c(self) -> float:
        return self.temperature_dc / 10.0


@dataclass(frozen=True)
class BodyState:
    """Navdata in REP 103 terms (body FLU, radians, metres, m/s), as ardrone_autonomy converts."""

    roll_rad: float
    pitch_rad: float  # nose down positive (REP 103 rotation about y-left)
    yaw_rad: float  # counter-clockwise positive
    altitude_m: float
    vx_m_s: float  # forward
    vy_m_s: float  # left
    vz_m_s: float  # up
    battery_pct: float
    ctrl_state: CtrlState | int
    flying: bool


@dataclass(frozen=True)
class Navdata:
    """One decoded navdata packet."""

    state: DroneState
    sequence: int
    vision_flag: int = 0
    demo: Demo | None = None
    gps: Gps | None = None
    unknown: tuple[tuple[int, bytes], ...] = ()  # (tag, payload) of options this codec skips
    pressure: PressureRaw | None = None  # tag 21, when general:navdata_options asks for it
    checksum: int = field(default=0, compare=False)  # as received; recomputed on encode

    @property
    def bootstrap(self) -> bool:
        return bool(self.state & DroneState.NAVDATA_BOOTSTRAP)

    def to_body(self) -> BodyState:
        """REP 103 view: rotX = phi, rotY = −theta, rotZ = −psi, vy = −vy, vz = −vz.

        Raises:
            ValueError: the packet has no demo option (bootstrap packets carry none).
        """
        d = self.demo
        if d is None:
            raise ValueError("navdata has no demo option; no body state to give")
        mdeg = math.pi / 180000.0
        return BodyState(
            roll_rad=d.phi_mdeg * mdeg,
            pitch_rad=-d.theta_mdeg * mdeg,
            yaw_rad=-d.psi_mdeg * mdeg,
            altitude_m=d.altitude_mm / 1000.0,
            vx_m_s=d.vx_mm_s / 1000.0,
            vy_m_s=-d.vy_mm_s / 1000.0,
            vz_m_s=-d.vz_mm_s / 1000.0,
            battery_pct=float(d.battery_pct),
            ctrl_state=d.major,
            flying=bool(self.state & DroneState.FLY),
        )


def ros_navdata_fields(nav: Navdata, tm_us: float = 0.0) -> dict[str, Any]:
    """The ``ardrone_autonomy/Navdata`` message fields (all but ``header``), converted exactly as
    ardrone_autonomy's ``ardrone_driver.cpp`` does: ``state`` = major control state, rotX = phi,
    rotY = −theta, rotZ = −psi (degrees), altd in mm, vx, vy = −vy, vz = −vz (mm/s), ``tm`` in µs.
    ``pressure`` (Pa) and ``temp`` (0.1 °C) come from the raw-pressure option when the packet
    has one. Fields no decoded option carries (magnetometer, wind, accelerations, motors, tags)
    are zero/empty. A packet without demo option gives zeros and ``state`` 0 (unknown).
    """
    d = nav.demo
    fields: dict[str, Any] = {
        "batteryPercent": float(d.battery_pct) if d else 0.0,
        "state": int(d.ctrl_state >> 16) if d else 0,
        "magX": 0,
        "magY": 0,
        "magZ": 0,
        "pressure": nav.pressure.pressure_pa if nav.pressure else 0,
        "temp": nav.pressure.temperature_dc if nav.pressure else 0,
        "wind_speed": 0.0,
        "wind_angle": 0.0,
        "wind_comp_angle": 0.0,
        "rotX": d.phi_mdeg / 1000.0 if d else 0.0,
        "rotY": -d.theta_mdeg / 1000.0 if d else 0.0,
        "rotZ": -d.psi_mdeg / 1000.0 if d else 0.0,
        "altd": int(d.altitude_mm) if d else 0,
        "vx": d.vx_mm_s if d else 0.0,
        "vy": -d.vy_mm_s if d else 0.0,
        "vz": -d.vz_mm_s if d else 0.0,
        "ax": 0.0,
        "ay": 0.0,
        "az": 0.0,
        "motor1": 0,
        "motor2": 0,
        "motor3": 0,
        "motor4": 0,
        "tags_count": 0,
        "tags_type": [],
        "tags_xc": [],
        "tags_yc": [],
        "tags_width": [],
        "tags_height": [],
        "tags_orientation": [],
        "tags_distance": [],
        "tm": float(tm_us),
    }
    return fields


def _u32(value: int) -> int:
    return value & 0xFFFFFFFF


def encode_navdata(nav: Navdata) -> bytes:
    """Encode a packet: header, demo (if any), GPS (only if given), unknown options, checksum.

    Raises:
        struct.error: never for values produced by :func:`decode_navdata`; a float field that
            is not a float or an out-of-range integer raises ``ValueError`` from ``struct``.
    """
    parts = [_HEADER.pack(NAVDATA_MAGIC, _u32(int(nav.state)), _u32(nav.sequence), nav.vision_flag)]
    if nav.demo is not None:
        d = nav.demo
        parts.append(_OPTION.pack(TAG_DEMO, DEMO_SIZE))
        parts.append(
            _DEMO.pack(
                d.ctrl_state,
                d.battery_pct,
                d.theta_mdeg,
                d.phi_mdeg,
                d.psi_mdeg,
                d.altitude_mm,
                d.vx_mm_s,
                d.vy_mm_s,
                d.vz_mm_s,
                d.num_frames,
            )
        )
        parts.append(bytes(_DEMO_PAD))
    if nav.pressure is not None:
        pr = nav.pressure
        parts.append(_OPTION.pack(TAG_PRESSURE_RAW, PRESSURE_SIZE))
        parts.append(_PRESSURE.pack(pr.up, pr.ut, pr.temperature_dc, pr.pressure_pa))
    if nav.gps is not None:
        g = nav.gps
        parts.append(_OPTION.pack(TAG_GPS, GPS_SIZE))
        parts.append(g.pack())
    for tag, payload in nav.unknown:
        parts.append(_OPTION.pack(tag, len(payload) + _OPTION.size))
        parts.append(payload)
    body = b"".join(parts)
    return body + _CKS.pack(TAG_CHECKSUM, CHECKSUM_SIZE, sum(body) & 0xFFFFFFFF)


def decode_navdata(data: bytes) -> Navdata:
    """Decode one navdata datagram.

    Raises:
        NavdataTruncatedError: shorter than the 16-byte header, or an option runs past the end.
        NavdataMagicError: the first u32 is not 0x55667788.
        NavdataOptionSizeError: an option size below 4, a demo option not 148 bytes, a GPS
            option not 216 bytes, or a checksum option not 8 bytes.
        NavdataChecksumError: no checksum option, or its value differs from the byte sum.
    """
    data = bytes(data)
    if len(data) >= 4 and int.from_bytes(data[:4], "little") != NAVDATA_MAGIC:
        raise NavdataMagicError(f"navdata magic is {data[:4].hex()}, expected 88776655")
    if len(data) < _HEADER.size:
        raise NavdataTruncatedError(f"navdata of {len(data)} bytes is shorter than its header")
    _, state, sequence, vision = _HEADER.unpack_from(data, 0)
    demo: Demo | None = None
    gps: Gps | None = None
    pressure: PressureRaw | None = None
    unknown: list[tuple[int, bytes]] = []
    offset = _HEADER.size
    while True:
        if offset + _OPTION.size > len(data):
            if offset == len(data):
                raise NavdataChecksumError("navdata has no checksum option")
            raise NavdataTruncatedError(f"option header at byte {offset} runs past the end")
        tag, size = _OPTION.unpack_from(data, offset)
        if size < _OPTION.size:
            raise NavdataOptionSizeError(f"option tag {tag} at byte {offset} has size {size} < 4")
        if offset + size > len(data):
            raise NavdataTruncatedError(f"option tag {tag} of {size} bytes runs past the end")
        if tag == TAG_CHECKSUM:
            if size != CHECKSUM_SIZE:
                raise NavdataOptionSizeError(f"checksum option has size {size}, expected 8")
            (cks,) = struct.unpack_from("<I", data, offset + 4)
            expected = sum(data[:offset]) & 0xFFFFFFFF
            if cks != expected:
                raise NavdataChecksumError(f"checksum {cks} != byte sum {expected}")
            break
        if tag == TAG_DEMO:
            if size != DEMO_SIZE:
                raise NavdataOptionSizeError(f"demo option has size {size}, expected {DEMO_SIZE}")
            demo = Demo(*_DEMO.unpack_from(data, offset + 4))
        elif tag == TAG_PRESSURE_RAW and size == PRESSURE_SIZE:
            pressure = PressureRaw(*_PRESSURE.unpack_from(data, offset + 4))
        elif tag == TAG_GPS and size == GPS_SIZE:
            gps = Gps.unpack(data, offset + 4)
        else:
            # Tag 27 is also ZIMMU_3000 on firmware < 2.4 (navdata_keys.h); any other size there
            # is that option, skipped like every unknown one.
            unknown.append((tag, data[offset + 4 : offset + size]))
        offset += size
    return Navdata(
        state=DroneState(state),
        sequence=sequence,
        vision_flag=vision,
        demo=demo,
        gps=gps,
        unknown=tuple(unknown),
        checksum=cks,
        pressure=pressure,
    )


def navdata_init_datagram() -> bytes:
    """What a client sends to UDP 5554 to start the stream (ARDroneLib sends int32 1)."""
    return b"\x01\x00\x00\x00"
