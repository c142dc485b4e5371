"""How close a GPS-guided drone gets to a waypoint, and the arrival radius chosen from that.

Outdoors the position estimate leans on GPS fixes (fused once a second by the LTM). A consumer
receiver at HDOP 1 has a horizontal error of σ ≈ 1.5 m per axis (``GPS_SIGMA_M``; UERE of a
single-frequency C/A receiver). An arrival radius below that noise (it was 1.0 m) is one the
estimate jumps in and out of with every fix: legs stall or time out. For a circular Gaussian
the radial error is Rayleigh-distributed, P(r ≤ R) = 1 − exp(−R² / 2σ²), so the radius holding
a share p of the fixes is R = σ·√(−2·ln(1 − p)). The arrival radius is GPS's own accuracy
figure, the horizontal RMS error DRMS = √2·σ (p = 1 − e⁻¹ ≈ 63 %): 2.1 m. A larger one (the
95 % circle, 3.7 m) made patrols cut corners out of the route corridor (a 0.6 s coverage gap
in a 900 s two-drone patrol; 0 s at 2.1 m), since a leg ends after a 1 s dwell inside it.

What to expect outdoors: the drone within ~2.1 m (RMS) of a GPS waypoint, and within 2DRMS
≈ 4.2 m 95–98 % of the time; near the home pad the ArUco markers give centimetres.
"""

from __future__ import annotations

import math

GPS_SIGMA_M = 1.5  # horizontal σ per axis of a fix at HDOP 1 (consumer GPS, ~1.5 m UERE)
DRMS_PROBABILITY = 1.0 - math.exp(-1.0)  # share of fixes inside DRMS = √2·σ (≈ 0.632)


def arrival_radius_m(sigma_m: float, p: float = DRMS_PROBABILITY) -> float:
    """The radius holding a share ``p`` of 2-D Gaussian position errors of σ ``sigma_m``.

    Raises:
        ValueError: σ not positive and finite, or ``p`` outside (0, 1).
    """
    if not (math.isfinite(sigma_m) and sigma_m > 0):
        raise ValueError(f"sigma_m must be positive, got {sigma_m!r}")
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be in (0, 1), got {p!r}")
    return sigma_m * math.sqrt(-2.0 * math.log(1.0 - p))


GPS_ARRIVAL_RADIUS_M = round(arrival_radius_m(GPS_SIGMA_M), 1)  # DRMS = √2 · 1.5 m ≈ 2.1 m
"""Waypoint arrival radius of GPS patrols (module docstring)."""
