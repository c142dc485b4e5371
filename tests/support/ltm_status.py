"""One LTM status for fleet tests: a landed drone at the origin unless told otherwise."""

from __future__ import annotations

from typing import Any

from server.fleet.geo import Enu
from server.fleet.messages import LtmStatus


def ltm_status(name: str = "uav1", **kw: Any) -> LtmStatus:
    """``name``'s status: landed at the origin, full battery, link up, sequence 1; ``kw``
    overrides any field."""
    base: dict[str, Any] = dict(
        name=name,
        t=0.0,
        seq=1,
        x=0.0,
        y=0.0,
        z=0.0,
        yaw_deg=0.0,
        lat=0.0,
        lon=0.0,
        battery_pct=100.0,
        flying=False,
        state="LANDED",
        link_ok=True,
        emergency=False,
        station=Enu(0.0, 0.0, 0.0),
    )
    base.update(kw)
    return LtmStatus(**base)
