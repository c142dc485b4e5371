"""Geodetic (WGS-84 latitude, longitude, altitude) <-> local ENU, with pymap3d.

The map frame outdoors is ENU at the world's ``gps_origin`` (docs/CONVENTIONS.md: x east,
y north, z up). pymap3d implements the standard ECEF-based conversion (ellipsoid WGS-84), so
waypoints given as lat/lon/alt land where a GPS receiver would put them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pymap3d

from server.fleet.errors import GeoError


@dataclass(frozen=True)
class Geo:
    """A WGS-84 point: degrees and metres above the ellipsoid."""

    lat_deg: float
    lon_deg: float
    alt_m: float

    def __post_init__(self) -> None:
        check_geo(self.lat_deg, self.lon_deg, self.alt_m)


@dataclass(frozen=True)
class Enu:
    """A point in the local ENU (map) frame, metres."""

    x: float
    y: float
    z: float

    def dist(self, other: Enu) -> float:
        return math.dist((self.x, self.y, self.z), (other.x, other.y, other.z))

    def dist_xy(self, other: Enu) -> float:
        return math.hypot(self.x - other.x, self.y - other.y)


def check_geo(lat: float, lon: float, alt: float) -> None:
    """Raise ``GeoError`` unless lat ∈ [−90, 90], lon ∈ [−180, 180], alt finite in ±100 km."""
    for name, v in (("lat", lat), ("lon", lon), ("alt", alt)):
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
            raise GeoError(f"{name} must be a finite number, got {v!r}")
    if not -90.0 <= lat <= 90.0:
        raise GeoError(f"lat {lat} is outside [-90, 90]")
    if not -180.0 <= lon <= 180.0:
        raise GeoError(f"lon {lon} is outside [-180, 180]")
    if not -1e5 <= alt <= 1e5:
        raise GeoError(f"alt {alt} m is outside ±100 km")


def to_enu(point: Geo, origin: Geo) -> Enu:
    """``point`` in the ENU frame at ``origin``."""
    e, n, u = pymap3d.geodetic2enu(
        point.lat_deg, point.lon_deg, point.alt_m, origin.lat_deg, origin.lon_deg, origin.alt_m
    )
    return Enu(float(e), float(n), float(u))


def to_geo(p: Enu, origin: Geo) -> Geo:
    """ENU point ``p`` (frame at ``origin``) as latitude/longitude/altitude."""
    for v in (p.x, p.y, p.z):
        if not math.isfinite(v):
            raise GeoError(f"ENU coordinates must be finite, got {p}")
    lat, lon, alt = pymap3d.enu2geodetic(
        p.x, p.y, p.z, origin.lat_deg, origin.lon_deg, origin.alt_m
    )
    return Geo(float(lat), float(lon), float(alt))


def origin_of(world: object) -> Geo | None:
    """The world's GPS origin as a ``Geo`` (None for worlds without one, e.g. indoor)."""
    o = getattr(world, "gps_origin", None)
    if o is None:
        return None
    return Geo(float(o.lat_deg), float(o.lon_deg), float(o.alt_m))
