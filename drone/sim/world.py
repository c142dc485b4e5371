"""Simulator worlds: rooms and fields with ArUco markers, furniture, stations and GPS origin.

A world is data (``worlds/*.yaml``) loaded into frozen dataclasses. Frames follow
docs/CONVENTIONS.md (REP 103): map frame x along the room's length, y across, z up, metres;
the indoor origin is a floor corner, the outdoor origin is the GPS origin (local ENU).

Marker convention (used by the renderer and by perception): ``Marker.position`` is the centre
of the black ArUco square, ``yaw_rad`` the direction of its outward normal in the map xy plane
(the way it faces), ``size_m`` the side of the black square (the printed white quiet zone
around it is extra). Its local frame is OpenCV's ArUco frame: x to the right as seen from the
front, y up, z out of the marker towards the viewer; ``Marker.corners()`` follows ArUco's
corner order (top-left, top-right, bottom-right, bottom-left) as ``cv2.aruco`` reports them.

Errors: every problem with a world file raises :class:`WorldError` naming the file and field.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drone.share import share_dir

WORLDS_DIR = share_dir("worlds")
"""Directory holding the named worlds (``indoor``, ``outdoor``)."""

ARUCO_DICTIONARY = "DICT_4X4_50"
"""The only dictionary the worlds use: ids 0..49."""
ARUCO_MAX_ID = 49

OBJECT_KINDS = frozenset(
    {
        "chair",
        "table",
        "door",
        "window",
        "person",
        "plant",
        "box",
        "sofa",
        "shelf",
        "lamp",
        "tree",
        "car",
        "post",
    }
)
"""Kinds of scene objects the renderer knows how to draw."""

COLOURS: dict[str, tuple[int, int, int]] = {
    # name -> BGR, distinct hues so the captioner can name them
    "red": (40, 40, 210),
    "green": (50, 170, 50),
    "blue": (200, 90, 30),
    "yellow": (40, 210, 230),
    "orange": (30, 130, 240),
    "purple": (150, 50, 130),
    "pink": (180, 130, 245),
    "brown": (40, 75, 120),
    "white": (235, 235, 235),
    "black": (35, 35, 35),
    "grey": (130, 130, 130),
    "cyan": (210, 200, 60),
    "light blue": (235, 205, 150),
}
"""Named colours (BGR) a world file may use without giving ``bgr`` explicitly."""


class WorldError(ValueError):
    """A world file is missing, unreadable or invalid; the message names the file and field."""


Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Bounds:
    """Axis-aligned box of the flyable volume (indoor: the room's walls, floor and ceiling)."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    z_min: float
    z_max: float

    def contains(self, x: float, y: float, z: float, margin: float = 0.0) -> bool:
        """True when (x, y, z) lies inside the box shrunk by ``margin`` on every side."""
        return (
            self.x_min + margin <= x <= self.x_max - margin
            and self.y_min + margin <= y <= self.y_max - margin
            and self.z_min + margin <= z <= self.z_max - margin
        )

    @property
    def size(self) -> Vec3:
        """(length x, width y, height z) in metres."""
        return (self.x_max - self.x_min, self.y_max - self.y_min, self.z_max - self.z_min)


@dataclass(frozen=True)
class GeoPoint:
    """WGS-84 latitude/longitude in degrees and altitude in metres."""

    lat_deg: float
    lon_deg: float
    alt_m: float


@dataclass(frozen=True)
class PlanarPose:
    """A start pose: position in the map frame and heading (yaw, CCW positive)."""

    x: float
    y: float
    z: float
    yaw_rad: float


@dataclass(frozen=True)
class Marker:
    """An ArUco marker (DICT_4X4_50) mounted vertically; see the module docstring."""

    id: int
    position: Vec3
    yaw_rad: float
    size_m: float

    @property
    def normal(self) -> np.ndarray:
        """Unit outward normal in the map frame."""
        return np.array([math.cos(self.yaw_rad), math.sin(self.yaw_rad), 0.0])

    def rotation(self) -> np.ndarray:
        """3×3 rotation map←marker (columns: marker x right, y up, z outward)."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.array([[-s, 0.0, c], [c, 0.0, s], [0.0, 1.0, 0.0]])

    def corners(self, margin: float = 0.0) -> np.ndarray:
        """(4, 3) map-frame corners in ArUco order (TL, TR, BR, BL) seen from the front.

        Args:
            margin: extra width added on every side (e.g. the white quiet zone), metres.
        """
        h = self.size_m / 2.0 + margin
        local = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
        out: np.ndarray = local @ self.rotation().T + np.asarray(self.position)
        return out

    def standoff(self, distance_m: float = 1.0) -> PlanarPose:
        """The pose ``distance_m`` in front of the marker at its height, facing it."""
        n = self.normal
        x, y, z = self.position
        return PlanarPose(
            x + n[0] * distance_m,
            y + n[1] * distance_m,
            z,
            math.atan2(-n[1], -n[0]),
        )


MAX_WALK_SPEED_M_S = 3.0  # a jog; anything faster in a world file is a typo


@dataclass(frozen=True)
class Walk:
    """Where a person walks (the simulator moves them: drone/sim/people.py): from the person's
    ``position`` through ``path`` (map-frame x, y) and back the same way, again and again, at
    ``speed_m_s`` varied by up to ±10 % by ``seed`` (people do not walk at a set speed)."""

    path: tuple[tuple[float, float], ...]
    speed_m_s: float
    seed: int = 0


@dataclass(frozen=True)
class SceneObject:
    """A piece of furniture, a door, a window, a person-like figure…

    ``position`` is the centre of the object's footprint on the floor (z = its base height),
    ``yaw_rad`` the direction its front faces, ``size`` = (width, depth, height) in metres.
    """

    id: str
    kind: str
    colour: str
    bgr: tuple[int, int, int]
    position: Vec3
    yaw_rad: float
    size: Vec3
    walk: Walk | None = None  # a person who walks (kind "person" only)

    @property
    def centre(self) -> Vec3:
        """Centre of the object's bounding box in the map frame."""
        x, y, z = self.position
        return (x, y, z + self.size[2] / 2.0)


PAD_RADIUS_M = 1.5  # a drone landed this close to a pad's centre sits on it (GPS-guided landings)
MAX_CHARGE_PCT_S = 10.0  # a full charge in 10 s at the most: anything faster is a typo


@dataclass(frozen=True)
class Station:
    """A home station (take-off and landing spot), map frame. A charging pad charges a drone
    landed on it (motors off) at ``charge_pct_s`` percent a second; 0 is a plain pad."""

    id: str
    position: Vec3
    charge_pct_s: float = 0.0
    radius_m: float = PAD_RADIUS_M

    def holds(self, x: float, y: float) -> bool:
        """Whether a drone at (x, y) sits on this pad."""
        return math.hypot(x - self.position[0], y - self.position[1]) <= self.radius_m


@dataclass(frozen=True)
class NamedWaypoint:
    """A named waypoint: map-frame (local ENU) position, and its geodetic point if known."""

    id: str
    position: Vec3
    geo: GeoPoint | None = None


@dataclass(frozen=True)
class Surfaces:
    """Colours (BGR) of the room's surfaces or the outdoor ground/sky, for the renderer."""

    floor: tuple[int, int, int] = (95, 120, 150)
    ceiling: tuple[int, int, int] = (225, 225, 220)
    walls: tuple[int, int, int] = (200, 205, 210)
    sky: tuple[int, int, int] = (235, 200, 150)
    tile_m: float = 0.5


@dataclass(frozen=True)
class World:
    """A simulator world: bounds, markers, objects, stations, GPS origin, waypoints."""

    name: str
    kind: str  # "indoor" (closed room: walls/floor/ceiling) or "outdoor" (ground and sky)
    bounds: Bounds
    markers: tuple[Marker, ...]
    objects: tuple[SceneObject, ...] = ()
    stations: tuple[Station, ...] = ()
    gps_origin: GeoPoint | None = None
    waypoints: tuple[NamedWaypoint, ...] = ()
    start: PlanarPose = PlanarPose(0.0, 0.0, 0.0, 0.0)
    surfaces: Surfaces = field(default_factory=Surfaces)
    source: str = ""
    # the file's ``limits:`` (drone.limits.limits_of); out of the hash (a dict), kept in ==
    limits: Mapping[str, float] | None = field(default=None, hash=False)

    @property
    def indoor(self) -> bool:
        """True for a closed room (rendered with walls and ceiling)."""
        return self.kind == "indoor"

    def marker(self, marker_id: int) -> Marker:
        """The marker with this id.

        Raises:
            KeyError: no such marker in this world.
        """
        for m in self.markers:
            if m.id == marker_id:
                return m
        raise KeyError(f"world {self.name!r} has no marker {marker_id}")

    def marker_ids(self) -> tuple[int, ...]:
        """Ids of all markers, in file order."""
        return tuple(m.id for m in self.markers)

    def pad_at(self, x: float, y: float) -> Station | None:
        """The station a drone at (x, y) sits on: the nearest whose pad holds it, or None."""
        on = [s for s in self.stations if s.holds(x, y)]
        if not on:
            return None
        return min(on, key=lambda s: math.hypot(x - s.position[0], y - s.position[1]))

    @property
    def charge_pct_s(self) -> float:
        """The fastest charging pad's rate (%/s); 0 when no pad charges."""
        return max((s.charge_pct_s for s in self.stations), default=0.0)

    def station(self, station_id: str) -> Station:
        """The station with this id (KeyError if absent)."""
        for s in self.stations:
            if s.id == station_id:
                return s
        raise KeyError(f"world {self.name!r} has no station {station_id!r}")

    def with_objects(self, objects: tuple[SceneObject, ...]) -> World:
        """A copy of this world with other objects (e.g. randomised placements for datasets)."""
        return replace(self, objects=tuple(objects))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description for ``GET /api/v1/world`` (degrees for people: ``yaw_deg``)."""
        b = self.bounds
        return {
            "name": self.name,
            "kind": self.kind,
            "frame": "map",
            "bounds": {
                "x_min": b.x_min,
                "x_max": b.x_max,
                "y_min": b.y_min,
                "y_max": b.y_max,
                "z_min": b.z_min,
                "z_max": b.z_max,
            },
            "markers": [
                {
                    "id": m.id,
                    "dictionary": ARUCO_DICTIONARY,
                    "position": {"x": m.position[0], "y": m.position[1], "z": m.position[2]},
                    "yaw_rad": m.yaw_rad,
                    "yaw_deg": math.degrees(m.yaw_rad),
                    "size_m": m.size_m,
                }
                for m in self.markers
            ],
            "stations": [
                {
                    "id": s.id,
                    "position": {"x": s.position[0], "y": s.position[1], "z": s.position[2]},
                    "charge_pct_s": s.charge_pct_s,
                    "radius_m": s.radius_m,
                }
                for s in self.stations
            ],
            "objects": [
                {
                    "id": o.id,
                    "kind": o.kind,
                    "colour": o.colour,
                    "position": {"x": o.position[0], "y": o.position[1], "z": o.position[2]},
                    "yaw_deg": math.degrees(o.yaw_rad),
                    "size": {"w": o.size[0], "d": o.size[1], "h": o.size[2]},
                    **(
                        {
                            "walk": {
                                "path": [{"x": x, "y": y} for x, y in o.walk.path],
                                "speed_m_s": o.walk.speed_m_s,
                            }
                        }
                        if o.walk is not None
                        else {}
                    ),
                }
                for o in self.objects
            ],
            "waypoints": [
                {
                    "id": w.id,
                    "position": {"x": w.position[0], "y": w.position[1], "z": w.position[2]},
                    **(
                        {
                            "lat": w.geo.lat_deg,
                            "lon": w.geo.lon_deg,
                            "alt": w.geo.alt_m,
                        }
                        if w.geo
                        else {}
                    ),
                }
                for w in self.waypoints
            ],
            "gps_origin": (
                None
                if self.gps_origin is None
                else {
                    "lat": self.gps_origin.lat_deg,
                    "lon": self.gps_origin.lon_deg,
                    "alt": self.gps_origin.alt_m,
                }
            ),
            "start": {
                "x": self.start.x,
                "y": self.start.y,
                "z": self.start.z,
                "yaw_deg": math.degrees(self.start.yaw_rad),
            },
            "limits": _limits_dict(self),
        }

    def to_json(self) -> str:
        """:meth:`to_dict` as compact JSON text."""
        return json.dumps(self.to_dict(), separators=(",", ":"))


# ---------------------------------------------------------------------------------------------
# loading and validation


class _Ctx:
    """Names the file and the field path in every error message."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, why: str) -> WorldError:
        return WorldError(f"{self.source}: {where}: {why}")

    def mapping(self, value: Any, where: str) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            raise self.fail(where, f"expected a mapping, got {type(value).__name__}")
        return value

    def seq(self, value: Any, where: str) -> list[Any]:
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.fail(where, f"expected a list, got {type(value).__name__}")
        return value

    def num(
        self, value: Any, where: str, lo: float | None = None, hi: float | None = None
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(where, f"expected a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise self.fail(where, f"must be finite, got {value!r}")
        if lo is not None and v < lo:
            raise self.fail(where, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            raise self.fail(where, f"must be <= {hi}, got {v}")
        return v

    def vec3(self, value: Any, where: str) -> Vec3:
        if not isinstance(value, list | tuple) or len(value) != 3:
            raise self.fail(where, f"expected [x, y, z], got {value!r}")
        return (
            self.num(value[0], f"{where}[0]"),
            self.num(value[1], f"{where}[1]"),
            self.num(value[2], f"{where}[2]"),
        )

    def text(self, value: Any, where: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(where, f"expected a non-empty string, got {value!r}")
        return value

    def bgr(self, value: Any, where: str) -> tuple[int, int, int]:
        if (
            not isinstance(value, list | tuple)
            or len(value) != 3
            or not all(isinstance(c, int) and not isinstance(c, bool) for c in value)
            or not all(0 <= c <= 255 for c in value)
        ):
            raise self.fail(where, f"expected [b, g, r] integers 0..255, got {value!r}")
        return (int(value[0]), int(value[1]), int(value[2]))

    def yaw(self, d: Mapping[str, Any], where: str, required: bool = True) -> float:
        """Yaw from ``yaw_deg`` (files are written for people) or ``yaw_rad``."""
        if "yaw_deg" in d:
            return math.radians(self.num(d["yaw_deg"], f"{where}.yaw_deg"))
        if "yaw_rad" in d:
            return self.num(d["yaw_rad"], f"{where}.yaw_rad")
        if required:
            raise self.fail(where, "missing field 'yaw_deg'")
        return 0.0

    def req(self, d: Mapping[str, Any], key: str, where: str) -> Any:
        if key not in d:
            raise self.fail(where, f"missing field {key!r}")
        return d[key]


def _parse_bounds(c: _Ctx, raw: Any) -> Bounds:
    d = c.mapping(raw, "bounds")
    vals = {k: c.num(c.req(d, k, "bounds"), f"bounds.{k}") for k in Bounds.__dataclass_fields__}
    b = Bounds(**vals)
    for ax in "xyz":
        if getattr(b, f"{ax}_max") <= getattr(b, f"{ax}_min"):
            raise c.fail(f"bounds.{ax}_max", f"must be greater than bounds.{ax}_min")
    return b


def _parse_marker(c: _Ctx, raw: Any, i: int, default_size: float | None) -> Marker:
    where = f"markers[{i}]"
    d = c.mapping(raw, where)
    mid = c.req(d, "id", where)
    if isinstance(mid, bool) or not isinstance(mid, int) or not 0 <= mid <= ARUCO_MAX_ID:
        raise c.fail(f"{where}.id", f"expected an integer 0..{ARUCO_MAX_ID} ({ARUCO_DICTIONARY})")
    if "size_m" in d:
        size = c.num(d["size_m"], f"{where}.size_m", lo=0.01, hi=5.0)
    elif default_size is not None:
        size = default_size
    else:
        raise c.fail(where, "missing field 'size_m' (and no marker_size_m default)")
    pos = c.vec3(c.req(d, "position", where), f"{where}.position")
    return Marker(id=mid, position=pos, yaw_rad=c.yaw(d, where), size_m=size)


def _parse_object(c: _Ctx, raw: Any, i: int) -> SceneObject:
    where = f"objects[{i}]"
    d = c.mapping(raw, where)
    kind = c.text(c.req(d, "kind", where), f"{where}.kind")
    if kind not in OBJECT_KINDS:
        raise c.fail(f"{where}.kind", f"unknown kind {kind!r}; known: {sorted(OBJECT_KINDS)}")
    colour = c.text(c.req(d, "colour", where), f"{where}.colour")
    if "bgr" in d:
        bgr = c.bgr(d["bgr"], f"{where}.bgr")
    elif colour in COLOURS:
        bgr = COLOURS[colour]
    else:
        raise c.fail(f"{where}.colour", f"unknown colour {colour!r} and no 'bgr' given")
    size_raw = c.req(d, "size", where)
    size = c.vec3(size_raw, f"{where}.size")
    for k, s in enumerate(size):
        if s <= 0:
            raise c.fail(f"{where}.size[{k}]", f"must be > 0, got {s}")
    oid = str(d.get("id", f"{kind}{i}"))
    walk = None
    if d.get("walk") is not None:
        if kind != "person":
            raise c.fail(f"{where}.walk", f"only people walk, not a {kind}")
        walk = _parse_walk(c, d["walk"], f"{where}.walk")
    return SceneObject(
        id=oid,
        kind=kind,
        colour=colour,
        bgr=bgr,
        position=c.vec3(c.req(d, "position", where), f"{where}.position"),
        yaw_rad=c.yaw(d, where, required=False),
        size=size,
        walk=walk,
    )


def _parse_walk(c: _Ctx, raw: Any, where: str) -> Walk:
    d = c.mapping(raw, where)
    points = c.seq(c.req(d, "path", where), f"{where}.path")
    if not points:
        raise c.fail(f"{where}.path", "needs at least one [x, y] point")
    path = []
    for k, pt in enumerate(points):
        if not isinstance(pt, list | tuple) or len(pt) != 2:
            raise c.fail(f"{where}.path[{k}]", f"expected [x, y], got {pt!r}")
        path.append((c.num(pt[0], f"{where}.path[{k}][0]"), c.num(pt[1], f"{where}.path[{k}][1]")))
    speed = c.num(c.req(d, "speed_m_s", where), f"{where}.speed_m_s", 0.01, MAX_WALK_SPEED_M_S)
    seed = d.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise c.fail(f"{where}.seed", f"expected an integer, got {seed!r}")
    return Walk(tuple(path), speed, seed)


def _parse_geo(c: _Ctx, raw: Any, where: str) -> GeoPoint:
    d = c.mapping(raw, where)
    return GeoPoint(
        lat_deg=c.num(c.req(d, "lat", where), f"{where}.lat", -90.0, 90.0),
        lon_deg=c.num(c.req(d, "lon", where), f"{where}.lon", -180.0, 180.0),
        alt_m=c.num(d.get("alt", 0.0), f"{where}.alt"),
    )


def parse_world(data: Any, source: str = "<memory>") -> World:  # noqa: C901
    """Build and validate a :class:`World` from a decoded YAML/JSON document.

    Complexity: one validation step per section and field of the world file, in the file's
    order, so that the function reads as its schema.

    Raises:
        WorldError: naming ``source`` and the offending field.
    """
    c = _Ctx(source)
    d = c.mapping(data, "document")
    name = c.text(c.req(d, "name", "document"), "name")
    kind = c.text(d.get("kind", "indoor"), "kind")
    if kind not in ("indoor", "outdoor"):
        raise c.fail("kind", f"expected 'indoor' or 'outdoor', got {kind!r}")
    bounds = _parse_bounds(c, c.req(d, "bounds", "document"))

    default_size = None
    if "marker_size_m" in d:
        default_size = c.num(d["marker_size_m"], "marker_size_m", lo=0.01, hi=5.0)
    markers = tuple(
        _parse_marker(c, m, i, default_size)
        for i, m in enumerate(c.seq(d.get("markers"), "markers"))
    )
    seen: set[int] = set()
    for i, m in enumerate(markers):
        if m.id in seen:
            raise c.fail(f"markers[{i}].id", f"duplicate marker id {m.id}")
        seen.add(m.id)
        if not bounds.contains(*m.position, margin=-0.05):
            raise c.fail(f"markers[{i}].position", f"{m.position} lies outside the bounds")
        if kind == "indoor" and not bounds.contains(*(np.asarray(m.position) + 0.3 * m.normal)):
            raise c.fail(f"markers[{i}].yaw_deg", "the marker faces out of the room (into a wall)")

    objects = tuple(
        _parse_object(c, o, i) for i, o in enumerate(c.seq(d.get("objects"), "objects"))
    )
    oids: set[str] = set()
    for i, o in enumerate(objects):
        if o.id in oids:
            raise c.fail(f"objects[{i}].id", f"duplicate object id {o.id!r}")
        oids.add(o.id)
        for k, (x, y) in enumerate(o.walk.path if o.walk is not None else ()):
            if not bounds.contains(x, y, bounds.z_min):
                raise c.fail(f"objects[{i}].walk.path[{k}]", f"({x}, {y}) lies outside the bounds")

    stations = []
    for i, s in enumerate(c.seq(d.get("stations"), "stations")):
        sd = c.mapping(s, f"stations[{i}]")
        pos = c.vec3(c.req(sd, "position", f"stations[{i}]"), f"stations[{i}].position")
        if not bounds.contains(*pos):
            raise c.fail(f"stations[{i}].position", f"{pos} lies outside the bounds")
        rate = c.num(
            sd.get("charge_pct_s", 0.0), f"stations[{i}].charge_pct_s", lo=0.0, hi=MAX_CHARGE_PCT_S
        )
        radius = c.num(sd.get("radius_m", PAD_RADIUS_M), f"stations[{i}].radius_m", lo=0.1, hi=10.0)
        sid = str(sd.get("id", f"home{i + 1}"))
        stations.append(Station(id=sid, position=pos, charge_pct_s=rate, radius_m=radius))

    gps = None
    if d.get("gps_origin") is not None:
        gps = _parse_geo(c, d["gps_origin"], "gps_origin")

    waypoints = []
    for i, w in enumerate(c.seq(d.get("waypoints"), "waypoints")):
        where = f"waypoints[{i}]"
        wd = c.mapping(w, where)
        wid = str(wd.get("id", f"wp{i + 1}"))
        if "position" in wd:
            pos = c.vec3(wd["position"], f"{where}.position")
            geo = None
            if gps is not None:
                geo = _enu_to_geo(gps, pos)
        elif "lat" in wd:
            if gps is None:
                raise c.fail(where, "lat/lon waypoints need a gps_origin")
            geo = _parse_geo(c, wd, where)
            pos = _geo_to_enu(gps, geo)
        else:
            raise c.fail(where, "missing field 'position' (or 'lat'/'lon')")
        waypoints.append(NamedWaypoint(id=wid, position=pos, geo=geo))

    start = PlanarPose(0.0, 0.0, 0.0, 0.0)
    if "start" in d:
        sd = c.mapping(d["start"], "start")
        sp = c.vec3(c.req(sd, "position", "start"), "start.position")
        if not bounds.contains(*sp):
            raise c.fail("start.position", f"{sp} lies outside the bounds")
        start = PlanarPose(sp[0], sp[1], sp[2], c.yaw(sd, "start", required=False))
    elif stations:
        p = stations[0].position
        start = PlanarPose(p[0], p[1], p[2], 0.0)

    surfaces = Surfaces()
    if "surfaces" in d:
        sd = c.mapping(d["surfaces"], "surfaces")
        kw: dict[str, Any] = {}
        for key in ("floor", "ceiling", "walls", "sky"):
            if key in sd:
                kw[key] = c.bgr(sd[key], f"surfaces.{key}")
        if "tile_m" in sd:
            kw["tile_m"] = c.num(sd["tile_m"], "surfaces.tile_m", lo=0.05, hi=100.0)
        surfaces = Surfaces(**kw)

    limits = _parse_limits(c, d["limits"]) if d.get("limits") is not None else None
    world = World(
        name=name,
        kind=kind,
        bounds=bounds,
        markers=markers,
        objects=objects,
        stations=tuple(stations),
        gps_origin=gps,
        waypoints=tuple(waypoints),
        start=start,
        surfaces=surfaces,
        source=source,
        limits=limits,
    )
    from drone.limits import LimitsError, limits_of

    try:
        limits_of(world)
    except LimitsError as exc:
        raise c.fail("limits", str(exc)) from None
    return world


def _limits_dict(world: World) -> dict[str, Any]:
    from drone.limits import limits_of

    lim = limits_of(world)
    return {
        "ceiling_m": lim.ceiling_m,
        "floor_m": lim.floor_m,
        "wall_margin_m": lim.wall_margin_m,
        "fence": {"x_min": lim.x_min, "x_max": lim.x_max, "y_min": lim.y_min, "y_max": lim.y_max},
    }


def _parse_limits(c: _Ctx, raw: Any) -> dict[str, float]:
    d = c.mapping(raw, "limits")
    known = ("ceiling_m", "floor_m", "wall_margin_m", "person_distance_m")
    for key in d:
        if key not in known:
            raise c.fail(f"limits.{key}", f"unknown limit; known: {', '.join(known)}")
    return {k: c.num(d[k], f"limits.{k}", lo=0.0) for k in known if k in d}


def _enu_to_geo(origin: GeoPoint, pos: Vec3) -> GeoPoint:
    import pymap3d

    lat, lon, alt = pymap3d.enu2geodetic(
        pos[0], pos[1], pos[2], origin.lat_deg, origin.lon_deg, origin.alt_m
    )
    return GeoPoint(float(lat), float(lon), float(alt))


def _geo_to_enu(origin: GeoPoint, geo: GeoPoint) -> Vec3:
    import pymap3d

    e, n, u = pymap3d.geodetic2enu(
        geo.lat_deg, geo.lon_deg, geo.alt_m, origin.lat_deg, origin.lon_deg, origin.alt_m
    )
    return (float(e), float(n), float(u))


def world_path(name_or_path: str) -> Path:
    """Resolve ``"indoor"``/``"outdoor"`` (any file in ``worlds/``) or a file path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml", ".json") or p.exists():
        return p
    return WORLDS_DIR / f"{name_or_path}.yaml"


def load_world(name_or_path: str) -> World:
    """Load a world by name (``"indoor"``, ``"outdoor"``) or from a YAML/JSON file path.

    Raises:
        WorldError: the file is missing, not YAML/JSON, or a field is invalid (message names
            the file and the field).
    """
    path = world_path(name_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        known = sorted(p.stem for p in WORLDS_DIR.glob("*.yaml"))
        raise WorldError(f"{path}: no such world file (named worlds: {known})") from None
    except (OSError, UnicodeDecodeError) as e:
        raise WorldError(f"{path}: cannot read: {e}") from e
    try:
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as e:
        raise WorldError(f"{path}: not valid {path.suffix[1:] or 'YAML'}: {e}") from e
    return parse_world(data, source=str(path))
