"""What :class:`~drone.mavlink.gcs.protocol.GcsProtocol` reports: the events it emits and the
telemetry snapshot it keeps (frozen dataclasses)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class VehicleFound:
    system_id: int
    autopilot: str
    vehicle_type: int


@dataclass(frozen=True)
class OtherVehicle:
    """A heartbeat from another system id on the same link (ignored)."""

    system_id: int


@dataclass(frozen=True)
class LinkLost:
    age_s: float
    failsafe: str  # what the autopilot will do, in words


@dataclass(frozen=True)
class LinkRestored:
    pass


@dataclass(frozen=True)
class CommandResult:
    """The end of one command: ``result`` is ACCEPTED, DENIED, …, or NO_ANSWER."""

    token: int
    command: str
    result: str
    reason: str | None = None
    cause: CommandResult | None = None  # NOT_SENT: the earlier command of the chain that failed

    @property
    def ok(self) -> bool:
        return self.result == "ACCEPTED"


@dataclass(frozen=True)
class CommandProgress:
    token: int
    command: str
    progress_pct: int


@dataclass(frozen=True)
class StatusText:
    severity: int
    text: str


@dataclass(frozen=True)
class MissionResult:
    ok: bool
    count: int
    detail: str


@dataclass(frozen=True)
class MissionItemReached:
    seq: int


@dataclass(frozen=True)
class MavlinkTelemetry:
    """What the vehicle last told (immutable). NaN where never heard."""

    system_id: int = 0
    autopilot: str = ""
    autopilot_id: int = 0
    mode: str = ""
    armed: bool = False
    system_status: int = 0
    landed_state: str = "UNDEFINED"
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    alt_amsl_m: float = math.nan
    rel_alt_m: float = math.nan
    vn: float = 0.0
    ve: float = 0.0
    vd: float = 0.0
    local_ned: tuple[float, float, float] | None = None
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    heading_rad: float = 0.0  # clockwise from north
    battery_pct: float = math.nan
    voltage_v: float = math.nan
    gps_fix: int = 0
    satellites: int = 0
    eph_m: float = math.nan
    sensors_ok: bool = False
    home: tuple[float, float, float] | None = None  # lat, lon, alt AMSL
    home_local: tuple[float, float, float] | None = None
    mission_current: int = -1
    last_heartbeat_t: float | None = None
    last_message_t: float | None = None
