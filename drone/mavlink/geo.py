"""Map frame (local ENU at the world's GPS origin) ↔ WGS-84 and ↔ MAVLink's local NED.

The map frame is REP 103 ENU (docs/CONVENTIONS.md); MAVLink's ``LOCAL_POSITION_NED`` and
``SET_POSITION_TARGET_LOCAL_NED`` are north-east-down with yaw clockwise from north
(mavlink.io "Coordinate Frames").

Geodetic conversions use the WGS-84 local tangent plane at the origin (meridian and prime-vertical
radii of curvature): over a world's ±60 m this agrees with pymap3d's exact ``enu2geodetic`` (what
the world loader uses for waypoints) to well under a millimetre (tests check it), and costs a
few multiplications instead of pymap3d's iterative ECEF round trip, which dominated the
simulated autopilot's telemetry (10 Hz per drone) in lockstep.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

WGS84_A = 6378137.0  # semi-major axis, m (NIMA TR8350.2)
WGS84_E2 = 6.69437999014e-3  # first eccentricity squared


@dataclass(frozen=True)
class Origin:
    """A WGS-84 origin: latitude/longitude in degrees, altitude AMSL in metres."""

    lat_deg: float
    lon_deg: float
    alt_m: float

    @property
    def _radii(self) -> tuple[float, float]:
        """(metres per radian of latitude, metres per radian of longitude) at the origin."""
        s = math.sin(math.radians(self.lat_deg))
        w = 1.0 - WGS84_E2 * s * s
        m = WGS84_A * (1.0 - WGS84_E2) / w**1.5 + self.alt_m  # meridian radius of curvature
        n = WGS84_A / math.sqrt(w) + self.alt_m  # prime vertical radius of curvature
        return m, n * math.cos(math.radians(self.lat_deg))

    def to_geo(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        """Map ENU (m) → (lat°, lon°, alt m AMSL)."""
        m, n = self._radii
        return (
            self.lat_deg + math.degrees(y / m),
            self.lon_deg + math.degrees(x / n),
            self.alt_m + z,
        )

    def to_map(self, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
        """(lat°, lon°, alt m AMSL) → map ENU (m)."""
        m, n = self._radii
        return (
            math.radians(lon - self.lon_deg) * n,
            math.radians(lat - self.lat_deg) * m,
            alt - self.alt_m,
        )


def enu_to_ned(x: float, y: float, z: float) -> tuple[float, float, float]:
    """ENU (east, north, up) → NED (north, east, down)."""
    return y, x, -z


def ned_to_enu(n: float, e: float, d: float) -> tuple[float, float, float]:
    """NED → ENU."""
    return e, n, -d


def yaw_enu_to_ned(yaw_rad: float) -> float:
    """Yaw CCW from east (REP 103) → heading clockwise from north, in (−π, π]."""
    return math.remainder(math.pi / 2.0 - yaw_rad, math.tau)


def yaw_ned_to_enu(yaw_rad: float) -> float:
    """Heading clockwise from north → yaw CCW from east (the map), in (−π, π]."""
    return math.remainder(math.pi / 2.0 - yaw_rad, math.tau)
