"""What every vehicle is, whatever its protocol: the :class:`Vehicle` protocol (typed snapshot,
modes, actions) that the AR.Drone's :class:`~drone.ardrone.vehicle.ARDroneVehicle` and the
MAVLink :class:`~drone.mavlink.vehicle.MavlinkVehicle` both implement, and the types it speaks.

The task executor, the supervisor, the LTM and the console's nodes use only this (MAVSDK's way:
a client never needs to know which autopilot answers); how a vehicle flies is its own business
(the AR.Drone's position loop runs on the vehicle; a MAVLink autopilot closes its own).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from drone.control.clock import Clock
from drone.control.loop import LoopStats
from drone.control.pid import PcmdCommand, Setpoint

__all__ = ["MarkerSeen", "Setpoint", "Vehicle", "VehicleMode", "VehicleSnapshot"]


class VehicleMode(enum.Enum):
    """Who is flying: nobody (drone's own hover), the position controller, or the operator."""

    IDLE = "idle"  # hover (PCMD flag 0) when flying
    AUTO = "auto"  # PID towards the setpoint
    MANUAL = "manual"  # operator jog
    LANDING = "landing"
    EMERGENCY = "emergency"


@dataclass(frozen=True)
class MarkerSeen:
    """One marker in the latest processed frame."""

    id: int
    distance_m: float
    x: float  # drone position this marker implies (map frame)
    y: float
    z: float
    yaw_rad: float
    marker_x: float  # the marker's own map pose
    marker_y: float
    marker_z: float
    marker_yaw_rad: float


@dataclass(frozen=True)
class VehicleSnapshot:
    """Everything one look at the vehicle tells (immutable)."""

    name: str
    t: float
    ctrl_state: str  # CtrlState name: LANDED, TAKEOFF, FLYING, HOVERING, LANDING, DEFAULT…
    flying: bool
    emergency: bool
    battery_pct: float
    altitude_m: float
    x: float
    y: float
    z: float
    yaw_rad: float
    vx: float
    vy: float
    vz: float
    position_sigma_m: float
    yaw_sigma_rad: float
    localised: bool
    markers: tuple[MarkerSeen, ...]
    last_marker_t: float | None
    link_ok: bool
    navdata_age_s: float | None
    mode: str
    setpoint: Setpoint | None
    controller: LoopStats | None
    state_bits: int = 0
    command: PcmdCommand | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    battery_known: bool = False  # navdata has carried a battery reading (demo option)
    estimator_disagreement: tuple[str, ...] = ()  # Estimate.disagreement
    estimator_reinits: int = 0  # EkfStats.navdata_reinits
    jog_limit: str = ""  # why the jog is being slowed/stopped near a limit ("" when it is not)
    navdata_doubt: str = ""  # why the driver doubts the navdata ("" while it trusts it)
    gps_age_s: float | None = None  # since the GPS option last carried a new fix (None: never)
    # The drone's own temperature reading, °C: the barometer's compensated temperature of the
    # raw-pressure option (tag 21, ardrone_autonomy's ``temp``), on the nav board inside the
    # hull, which the motors' and electronics' heat warms (None: no reading yet).
    temperature_c: float | None = None

    @property
    def yaw_deg(self) -> float:
        return math.degrees(self.yaw_rad)

    @property
    def marker_ids(self) -> tuple[int, ...]:
        return tuple(m.id for m in self.markers)


@runtime_checkable
class Vehicle(Protocol):
    """One drone as everything above the drivers sees it. Commands are thread-safe and return
    at once; ``snapshot`` is immutable. ``holds_position``: the vehicle holds a hover at its
    position by itself (an autopilot), so the task executor need not hold a setpoint there."""

    name: str
    clock: Clock
    holds_position: bool

    def snapshot(self) -> VehicleSnapshot: ...

    def takeoff(self) -> None: ...

    def land(self) -> None: ...

    def hover(self) -> None: ...

    def emergency(self) -> None: ...

    def reset(self) -> None: ...

    def jog(self, linear_x: float, linear_y: float, linear_z: float, angular_z: float) -> None:
        """The operator's ``/cmd_vel`` (fractions in [−1, 1], ardrone_autonomy's convention)."""
        ...

    def set_setpoint(self, setpoint: Setpoint | None) -> None:
        """Fly to ``setpoint`` (map frame); None: hold where it is."""
        ...

    @property
    def setpoint(self) -> Setpoint | None: ...

    def add_jog_listener(self, cb: Callable[[], None]) -> None:
        """Call ``cb()`` whenever the operator jogs (the task executor cancels its task)."""
        ...

    async def stop(self, *, land: bool = True) -> None:
        """Stop flying it: land (or hover when ``land`` is False), then stop its threads."""
        ...
