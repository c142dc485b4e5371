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
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

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


class Role(enum.Enum):
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


def _num(d: Mapping[str, Any], key: str, *, default: float | None = None) -> float:
    v = d.get(key, default)
    if v is None:
        raise MessageError(f"missing field {key!r}")
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise MessageError(f"field {key!r} must be a finite number, got {v!r}")
    return float(v)


def _str(d: Mapping[str, Any], key: str, default: str | None = None) -> str:
    v = d.get(key, default)
    if not isinstance(v, str):
        raise MessageError(f"field {key!r} must be a string, got {v!r}")
    return v


def _bool(d: Mapping[str, Any], key: str, default: bool | None = None) -> bool:
    v = d.get(key, default)
    if not isinstance(v, bool):
        raise MessageError(f"field {key!r} must be true or false, got {v!r}")
    return v


def _word(d: Mapping[str, Any], key: str) -> str:
    """A short free-text field (at most ``MAX_WORD`` characters, "" when absent)."""
    v = _str(d, key, "")
    if len(v) > MAX_WORD:
        raise MessageError(f"field {key!r} is longer than {MAX_WORD} characters")
    return v


def _mapping(obj: Any, what: str) -> Mapping[str, Any]:
    if not isinstance(obj, Mapping):
        raise MessageError(f"{what} must be a JSON object, got {type(obj).__name__}")
    return obj


def _point(obj: Any, what: str) -> Enu:
    d = _mapping(obj, what)
    return Enu(_num(d, "x"), _num(d, "y"), _num(d, "z"))


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
        d = _mapping(obj, "status")
        seq = d.get("seq", 0)
        if isinstance(seq, bool) or not isinstance(seq, int) or seq < 0:
            raise MessageError(f"field 'seq' must be a non-negative integer, got {seq!r}")
        pid = d.get("plan_id", 0)
        if isinstance(pid, bool) or not isinstance(pid, int):
            raise MessageError(f"field 'plan_id' must be an integer, got {pid!r}")
        name = _str(d, "name")
        if not name:
            raise MessageError("field 'name' must not be empty")
        return cls(
            name=name,
            t=_num(d, "t"),
            seq=seq,
            x=_num(d, "x"),
            y=_num(d, "y"),
            z=_num(d, "z"),
            yaw_deg=_num(d, "yaw_deg", default=0.0),
            lat=_num(d, "lat", default=0.0),
            lon=_num(d, "lon", default=0.0),
            battery_pct=_num(d, "battery_pct"),
            flying=_bool(d, "flying"),
            state=_str(d, "state"),
            link_ok=_bool(d, "link_ok"),
            emergency=_bool(d, "emergency", False),
            station=_point(d.get("station"), "station"),
            plan_id=pid,
            task=_str(d, "task", ""),
            task_state=_str(d, "task_state", "idle"),
            progress=_num(d, "progress", default=0.0),
            autonomous=_str(d, "autonomous", ""),
            operator=_word(d, "operator"),
            held=_word(d, "held"),
            battery_known=_bool(d, "battery_known", True),
        )


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
        d = _mapping(obj, "flight plan")
        try:
            kind = PlanKind(d.get("kind"))
        except ValueError:
            kinds = ", ".join(k.value for k in PlanKind)
            raise MessageError(
                f"field 'kind' must be one of {kinds}, got {d.get('kind')!r}"
            ) from None
        raw = d.get("route", [])
        if not isinstance(raw, list):
            raise MessageError("field 'route' must be a list of {x, y, z}")
        route = tuple(_point(p, f"route[{i}]") for i, p in enumerate(raw))
        if kind is PlanKind.PATROL and not route:
            raise MessageError("a patrol plan needs a non-empty 'route'")
        pid = d.get("plan_id")
        if isinstance(pid, bool) or not isinstance(pid, int):
            raise MessageError(f"field 'plan_id' must be an integer, got {pid!r}")
        start = d.get("start_index", 0)
        if isinstance(start, bool) or not isinstance(start, int):
            raise MessageError(f"field 'start_index' must be an integer, got {start!r}")
        if route and not 0 <= start < len(route):
            raise MessageError(f"field 'start_index' {start} is outside the route")
        tol = _num(d, "tolerance_m", default=1.0)
        if tol <= 0:
            raise MessageError("field 'tolerance_m' must be > 0")
        heads = d.get("headings_deg", [])
        if not isinstance(heads, list) or (heads and len(heads) != len(route)):
            raise MessageError("field 'headings_deg' must be a list with one heading a waypoint")
        headings = tuple(_num({"h": h}, "h") for h in heads)
        join = _point(d["join"], "join") if d.get("join") is not None else None
        return cls(
            join=join,
            headings_deg=headings,
            plan_id=pid,
            kind=kind,
            mission=_str(d, "mission", ""),
            route=route,
            loop=_bool(d, "loop", True),
            start_index=start,
            cruise_z=_num(d, "cruise_z", default=5.0),
            tolerance_m=tol,
        )


# Bounds of a mission request (issue 14: a mission named "a/b" or 100 KB long could not be
# stopped; routes and mission counts were unbounded). A name is a URL path segment.
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
