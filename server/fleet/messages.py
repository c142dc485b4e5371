"""Typed fleet messages: LTM status, flight plans, missions, and their JSON forms.

On the graph and over rosbridge they travel as ``std_msgs/String`` whose ``data`` is the JSON of
``to_dict()`` (status topic ``/NAME/fleet/ltm_status``) or as the args of the flight-plan service
``/NAME/fleet/flight_plan``; ``from_dict`` checks every field and raises ``MessageError`` naming
the first bad one, so nothing malformed gets past the door.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Annotated, Any, Self

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from server.fleet.errors import MessageError
from server.fleet.geo import Enu

STATUS_TOPIC = "fleet/ltm_status"  # prefixed /NAME/
PLAN_SERVICE = "fleet/flight_plan"  # prefixed /NAME/
STATUS_TYPE = "std_msgs/String"
PLAN_SERVICE_TYPE = "uav_console/FlightPlan"
FLEET_TOPIC = "/fleet/status"
FLEET_TYPE = "uav_console/FleetStatus"
# The Central patrol (the console's buttons, "start/stop/pause/resume the patrol"): args
# {op: start|stop|pause|resume, threshold?} -> {ok, text, mission}; a vehicle process's dialog
# calls it over the link.
PATROL_SERVICE = "/fleet/patrol"
PATROL_SERVICE_TYPE = "uav_console/Patrol"
MAX_WORD = 64  # a status's free-text words (``operator``)


class DroneRole(enum.Enum):
    """What the CTM has a drone doing (``/fleet/status`` roles)."""

    PATROLLING = "patrolling"
    RELIEVING = "relieving"
    RETURNING = "returning"
    CHARGING = "charging"
    IDLE = "idle"
    LOST = "lost"
    # in a paused mission (server.fleet.states): the CTM sends it nothing; it does what the
    # operator last told it (landed, hovering) or holds where it was
    PAUSED = "paused"


class Handoff(enum.Enum):
    """When the patrolling drone hands over (``POST /missions``' ``handoff``).

    ``predictive``: its relief is sent ahead so it is on the route when the patrolling drone
    reaches the threshold (no gap). ``reactive``: the paper's rule, the patrolling drone leaves
    when its battery drops below the threshold and its relief is sent then (a gap of the relief's
    flight to the route at each handoff)."""

    PREDICTIVE = "predictive"
    REACTIVE = "reactive"


class PlanKind(enum.Enum):
    PATROL = "patrol"  # take off if needed, fly the route (loop) from ``start_index``
    RETURN = "return"  # fly to the station at ``cruise_z`` and land
    HOLD = "hold"  # hover where it is
    NONE = "none"  # cancel; hover if flying


def _finite(value: Any, info: ValidationInfo) -> float:
    """A JSON number that is finite (``true`` is no number), as a float."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"field {info.field_name!r} must be a finite number, got {value!r}")
    return float(value)


def _integer(value: Any, info: ValidationInfo) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"field {info.field_name!r} must be an integer, got {value!r}")
    return value


def _text(value: Any, info: ValidationInfo) -> str:
    if not isinstance(value, str):
        raise ValueError(f"field {info.field_name!r} must be a string, got {value!r}")
    return value


def _flag(value: Any, info: ValidationInfo) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"field {info.field_name!r} must be true or false, got {value!r}")
    return value


def _word(value: Any, info: ValidationInfo) -> str:
    """A short free-text field (at most ``MAX_WORD`` characters)."""
    text = _text(value, info)
    if len(text) > MAX_WORD:
        raise ValueError(f"field {info.field_name!r} is longer than {MAX_WORD} characters")
    return text


Finite = Annotated[float, BeforeValidator(_finite)]
Integer = Annotated[int, BeforeValidator(_integer)]
Text = Annotated[str, BeforeValidator(_text)]
Flag = Annotated[bool, BeforeValidator(_flag)]
Word = Annotated[str, BeforeValidator(_word)]


class _Message(BaseModel):
    """The fields of a fleet message as they arrive (unknown fields are ignored: a newer
    peer may send more)."""

    model_config = ConfigDict(frozen=True, extra="ignore")

    @classmethod
    def read(cls, obj: Any, what: str) -> Self:
        """``obj`` checked field by field.

        Raises:
            MessageError: not a JSON object, or the first bad field, named.
        """
        if not isinstance(obj, Mapping):
            raise MessageError(f"{what} must be a JSON object, got {type(obj).__name__}")
        try:
            return cls.model_validate(dict(obj))
        except ValidationError as exc:
            raise MessageError(_first_error(what, exc)) from None


def _first_error(what: str, exc: ValidationError) -> str:
    err = exc.errors(include_url=False)[0]
    where = ".".join(str(p) for p in err["loc"])
    if err["type"] == "value_error":
        return str(err["ctx"]["error"])
    if err["type"] == "missing":
        return f"missing field {where!r}"
    return f"{what}: field {where!r}: {err['msg']}"


class _Point(_Message):
    x: Finite
    y: Finite
    z: Finite

    @property
    def enu(self) -> Enu:
        return Enu(self.x, self.y, self.z)


class _StatusFields(_Message):
    """:class:`LtmStatus` on the wire."""

    name: Text
    t: Finite
    seq: Integer = 0
    x: Finite
    y: Finite
    z: Finite
    yaw_deg: Finite = 0.0
    lat: Finite = 0.0
    lon: Finite = 0.0
    battery_pct: Finite
    flying: Flag
    state: Text
    link_ok: Flag
    emergency: Flag = False
    station: _Point
    plan_id: Integer = 0
    task: Text = ""
    task_state: Text = "idle"
    progress: Finite = 0.0
    autonomous: Text = ""
    operator: Word = ""
    held: Word = ""
    battery_known: Flag = True

    @field_validator("name")
    @classmethod
    def _named(cls, value: str) -> str:
        if not value:
            raise ValueError("field 'name' must not be empty")
        return value

    @field_validator("seq")
    @classmethod
    def _counted(cls, value: int) -> int:
        if value < 0:
            raise ValueError(f"field 'seq' must be a non-negative integer, got {value!r}")
        return value


class _PlanFields(_Message):
    """:class:`FlightPlan` on the wire (kind-dependent rules in ``FlightPlan.from_dict``)."""

    plan_id: Integer
    kind: Any = None
    mission: Text = ""
    route: list[_Point] = Field(default_factory=list)
    loop: Flag = True
    start_index: Integer = 0
    cruise_z: Finite = 5.0
    tolerance_m: Finite = 1.0
    headings_deg: list[Finite] = Field(default_factory=list)
    join: _Point | None = None

    @field_validator("route", "headings_deg", mode="before")
    @classmethod
    def _listed(cls, value: Any, info: ValidationInfo) -> Any:
        if not isinstance(value, list):
            what = "{x, y, z}" if info.field_name == "route" else "headings"
            raise ValueError(f"field {info.field_name!r} must be a list of {what}")
        return value


@dataclass(frozen=True)
class LtmStatus:
    """What an LTM reports about its drone, periodically (default 1 Hz)."""

    name: str
    t: float  # LTM clock, seconds
    seq: int
    x: float
    y: float
    z: float
    yaw_deg: float
    lat: float
    lon: float
    battery_pct: float
    flying: bool
    state: str  # ctrl state (LANDED, FLYING, HOVERING…) or EMERGENCY
    link_ok: bool  # the LTM hears its drone
    emergency: bool
    station: Enu
    plan_id: int = 0  # last plan applied (0: none)
    task: str = ""  # running task name
    task_state: str = "idle"
    progress: float = 0.0
    autonomous: str = ""  # what the LTM did on its own ("ctm_silent", "battery_reserve")
    # what the operator did to the CTM's patrol plan (land, hover, emergency, stop, jog…), from
    # any door (page, REST, speech, rosbridge, the safety door): "" until then, and again once
    # the next plan is applied
    operator: str = ""
    # what the drone's own safety holds it for, asking the operator ("navdata monitor (hover)":
    # a safety monitor's hover that waits for the operator to say), until the next plan
    held: str = ""
    battery_known: bool = True  # navdata has carried a battery reading (else battery_pct is 0)

    @property
    def position(self) -> Enu:
        return Enu(self.x, self.y, self.z)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, obj: Any) -> LtmStatus:
        """Raises: MessageError naming the first bad field."""
        d = _StatusFields.read(obj, "status")
        fields = {k: getattr(d, k) for k in type(d).model_fields if k != "station"}
        return cls(**fields, station=d.station.enu)


@dataclass(frozen=True)
class FlightPlan:
    """A plan the CTM sends an LTM; the LTM turns it into task-manager commands."""

    plan_id: int
    kind: PlanKind
    mission: str = ""
    route: tuple[Enu, ...] = ()
    loop: bool = True
    start_index: int = 0
    cruise_z: float = 5.0  # transit height to and from the station
    tolerance_m: float = 1.0  # waypoint arrival radius outdoors
    # per waypoint, the heading to hold there (indoors: face the marker so the camera keeps
    # localising); empty: face along the route
    headings_deg: tuple[float, ...] = ()
    # where to enter the route before waypoint ``start_index`` (a point of the route; None:
    # straight to the waypoint); a replacement enters on the lost drone's leg, nearest its pad
    join: Enu | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "plan_id": self.plan_id,
            "kind": self.kind.value,
            "mission": self.mission,
            "route": [{"x": p.x, "y": p.y, "z": p.z} for p in self.route],
            "loop": self.loop,
            "start_index": self.start_index,
            "cruise_z": self.cruise_z,
            "tolerance_m": self.tolerance_m,
            **({"headings_deg": list(self.headings_deg)} if self.headings_deg else {}),
            **({"join": {"x": j.x, "y": j.y, "z": j.z}} if (j := self.join) is not None else {}),
        }

    @classmethod
    def from_dict(cls, obj: Any) -> FlightPlan:
        """Raises: MessageError naming the first bad field."""
        d = _PlanFields.read(obj, "flight plan")
        try:
            kind = PlanKind(d.kind)
        except ValueError:
            kinds = ", ".join(k.value for k in PlanKind)
            raise MessageError(f"field 'kind' must be one of {kinds}, got {d.kind!r}") from None
        route = tuple(p.enu for p in d.route)
        if kind is PlanKind.PATROL and not route:
            raise MessageError("a patrol plan needs a non-empty 'route'")
        start = d.start_index
        if route and not 0 <= start < len(route):
            raise MessageError(f"field 'start_index' {start} is outside the route")
        if d.tolerance_m <= 0:
            raise MessageError("field 'tolerance_m' must be > 0")
        if d.headings_deg and len(d.headings_deg) != len(route):
            raise MessageError("field 'headings_deg' must be a list with one heading a waypoint")
        return cls(
            join=None if d.join is None else d.join.enu,
            headings_deg=tuple(d.headings_deg),
            plan_id=d.plan_id,
            kind=kind,
            mission=d.mission,
            route=route,
            loop=d.loop,
            start_index=start,
            cruise_z=d.cruise_z,
            tolerance_m=d.tolerance_m,
        )


# Bounds of a mission request. A name is a URL path segment (a mission named "a/b" or 100 KB
# long could not be stopped by name); routes and mission counts are bounded too.
MISSION_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
MAX_ROUTE_POINTS = 200


class GeoWaypoint(BaseModel):
    model_config = ConfigDict(allow_inf_nan=False)

    lat: float = Field(ge=-90, le=90)
    lon: float = Field(ge=-180, le=180)
    alt: float | None = Field(default=None, description="metres above the ellipsoid")


class MissionRequest(BaseModel):
    """``POST /api/v1/missions``: a patrol route as lat/lon/alt waypoints or marker ids."""

    model_config = ConfigDict(allow_inf_nan=False)

    waypoints: list[GeoWaypoint] | None = Field(default=None, max_length=MAX_ROUTE_POINTS)
    markers: list[int] | None = Field(default=None, max_length=MAX_ROUTE_POINTS)
    altitude_m: float = Field(default=5.0, gt=0.3, le=100, description="height over the origin")
    loop: bool = True
    handoff_threshold: float = Field(default=0.30, gt=0.0, lt=1.0)
    handoff: Handoff = Field(
        default=Handoff.PREDICTIVE,
        description="predictive: the relief is on the route before the threshold; reactive: "
        "the patrolling drone leaves at the threshold and the relief is sent then (the paper)",
    )
    name: str | None = Field(
        default=None,
        pattern=MISSION_NAME_PATTERN,
        description="1-64 letters, digits, '_', '.', '-' (it names the mission in URLs)",
    )

    @model_validator(mode="after")
    def _one_route(self) -> MissionRequest:
        has_w, has_m = bool(self.waypoints), bool(self.markers)
        if has_w == has_m:
            raise ValueError("give exactly one non-empty route: 'waypoints' or 'markers'")
        return self


@dataclass(frozen=True)
class Mission:
    """A mission the CTM holds: a route in the map frame, loop, handoff threshold."""

    id: str
    route: tuple[Enu, ...]
    loop: bool = True
    threshold: float = 0.30  # battery fraction at which the patrolling drone must leave
    created_t: float = 0.0
    geo: tuple[tuple[float, float, float], ...] = field(default=())
    headings_deg: tuple[float, ...] = ()  # per waypoint (FlightPlan.headings_deg)
    handoff: Handoff = Handoff.PREDICTIVE

    @property
    def altitude_m(self) -> float:
        return sum(p.z for p in self.route) / len(self.route)
