"""Handoff timing and the persistent-coverage bound, as plain functions of a flight model.

The replacement must reach the handoff point before the patrolling drone has to leave.
With battery ``b`` (%), drain ``r`` (%/s) and threshold ``θ`` (%), the active drone must leave
in ``t_leave = (b − θ) / r``. The replacement needs ``t_lead = t_takeoff + d_h / v + Δz / v_z +
margin`` to get there, so the CTM dispatches it as soon as ``t_leave ≤ t_lead``.

Persistent coverage (the bound the measured coverage is held against): one drone's cycle is
``T_cycle = t_takeoff + t_out + T_on + t_back + t_land + t_restore`` of which ``T_on`` is on the
route, with ``T_on = (100 − θ)/r − t_takeoff − t_out`` (it leaves at θ). Coverage needs the ``N``
drones' on-route time to tile the timeline with overlap for each hand-over: ``N ≥ ⌈T_cycle /
(T_on − t_overlap)⌉`` (the classic bound for persistent UAV presence, cf. the testbed paper's
"number of UAVs needed for persistent coverage").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drone.sim.battery import FLIGHT_TIME_S
from server.fleet.errors import PlanError
from server.fleet.geo import Enu


@dataclass(frozen=True)
class FlightModel:
    """What the planner assumes about a drone (AR.Drone 2.0 defaults in the simulator).

    Attributes:
        speed_m_s: mean ground speed on transit (PID saturated at 12° tilt: ~2.3 m/s top,
            drone/sim/physics.py; 1.8 allows for acceleration and turns).
        climb_m_s: mean climb rate (control_vz_max 0.7 m/s, lagged).
        takeoff_s: REF take-off to hovering (~2.5 s in the simulator) plus the plan round trip.
        land_s: landing from cruise height at ~0.5 m/s plus the descent leg.
        drain_pct_s: battery drain in flight (100 % / 720 s, drone/sim/battery.py).
        margin_s: extra lead so the relief is on the route before the threshold.
        min_shift_s: the least time on the route worth a take-off: a drone is able to fly a
            mission when its charge covers the flight out and this long above the threshold.
    """

    speed_m_s: float = 1.8
    climb_m_s: float = 0.6
    takeoff_s: float = 4.0
    land_s: float = 12.0
    drain_pct_s: float = 100.0 / FLIGHT_TIME_S
    margin_s: float = 15.0
    min_shift_s: float = 60.0

    @classmethod
    def for_flight_time(cls, flight_time_s: float) -> FlightModel:
        """The model of drones whose full battery hovers ``flight_time_s`` (100 % → 0 %): the
        drain follows, and the least shift worth a take-off scales with the battery (60 s of
        the AR.Drone's 12 minutes)."""
        if not (math.isfinite(flight_time_s) and flight_time_s > 0):
            raise PlanError(f"flight_time_s must be > 0, got {flight_time_s!r}")
        return cls(
            drain_pct_s=100.0 / flight_time_s, min_shift_s=60.0 * flight_time_s / FLIGHT_TIME_S
        )

    def __post_init__(self) -> None:
        for name in ("speed_m_s", "climb_m_s", "drain_pct_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise PlanError(f"{name} must be > 0, got {v!r}")
        for name in ("takeoff_s", "land_s", "margin_s", "min_shift_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise PlanError(f"{name} must be >= 0, got {v!r}")


@dataclass(frozen=True)
class StationModel:
    """How a station restores a drone: a battery swap taking ``swap_s`` (default 2 min), or,
    when ``charge_pct_s`` is set, charging at that rate."""

    swap_s: float = 120.0
    charge_pct_s: float | None = None
    ready_pct: float = 95.0  # a drone at or above this is ready to fly a shift

    def __post_init__(self) -> None:
        if not (math.isfinite(self.swap_s) and self.swap_s >= 0):
            raise PlanError(f"swap_s must be >= 0, got {self.swap_s!r}")
        if self.charge_pct_s is not None and not (
            math.isfinite(self.charge_pct_s) and self.charge_pct_s > 0
        ):
            raise PlanError(f"charge_pct_s must be > 0, got {self.charge_pct_s!r}")

    def restore_s(self, battery_pct: float) -> float:
        """Seconds from landing with ``battery_pct`` to ``ready_pct``."""
        return self.time_to_s(battery_pct, self.ready_pct, 0.0)

    def time_to_s(self, battery_pct: float, target_pct: float, since_s: float) -> float:
        """Seconds until a drone on its station, there for ``since_s`` with ``battery_pct``
        now, has ``target_pct``: charging at the rate, or when the swap is done."""
        if battery_pct >= target_pct:
            return 0.0
        if self.charge_pct_s is None:
            return max(0.0, self.swap_s - since_s)
        return (min(target_pct, 100.0) - battery_pct) / self.charge_pct_s


def transit_s(a: Enu, b: Enu, model: FlightModel) -> float:
    """Time to fly from ``a`` to ``b``: horizontal at ``speed``, vertical at ``climb``."""
    return a.dist_xy(b) / model.speed_m_s + abs(b.z - a.z) / model.climb_m_s


def lead_time_s(station: Enu, handoff: Enu, model: FlightModel) -> float:
    """Dispatch-to-arrival time of a replacement standing on ``station``, margin included."""
    return model.takeoff_s + transit_s(station, handoff, model) + model.margin_s


def time_to_threshold_s(battery_pct: float, threshold_pct: float, drain_pct_s: float) -> float:
    """Seconds until ``battery_pct`` drains to ``threshold_pct`` (0 if already below)."""
    if not drain_pct_s > 0:
        raise PlanError(f"drain rate must be > 0, got {drain_pct_s!r}")
    return max(0.0, battery_pct - threshold_pct) / drain_pct_s


def should_dispatch(
    battery_pct: float, threshold_pct: float, drain_pct_s: float, lead_s: float
) -> bool:
    """True when the replacement must leave now to arrive before the active drone must leave."""
    return time_to_threshold_s(battery_pct, threshold_pct, drain_pct_s) <= lead_s


def reserve_pct(
    position: Enu, station: Enu, model: FlightModel, *, extra_pct: float = 3.0
) -> float:
    """Battery needed to fly from ``position`` to ``station`` and land, plus ``extra_pct``."""
    cruise = Enu(station.x, station.y, max(position.z, 1.0))
    t = transit_s(position, cruise, model) + model.land_s
    return t * model.drain_pct_s + extra_pct


@dataclass(frozen=True)
class CoverageBound:
    """The analytic persistent-coverage bound for one route (see the module docstring)."""

    on_route_s: float
    cycle_s: float
    drones_needed: int
    coverage_upper: dict[int, float]  # N -> best possible long-run coverage fraction

    def as_dict(self) -> dict[str, object]:
        return {
            "on_route_s": round(self.on_route_s, 1),
            "cycle_s": round(self.cycle_s, 1),
            "drones_needed": self.drones_needed,
            "coverage_upper": {str(k): round(v, 4) for k, v in self.coverage_upper.items()},
        }


def coverage_bound(
    station: Enu,
    entry: Enu,
    threshold: float,
    model: FlightModel,
    station_model: StationModel,
    *,
    overlap_s: float | None = None,
    max_drones: int = 8,
) -> CoverageBound:
    """How many drones persistent coverage of a route entered at ``entry`` needs.

    Raises:
        PlanError: ``threshold`` outside (0, 1), or a shift too short to reach the route.
    """
    if not 0.0 < threshold < 1.0:
        raise PlanError(f"threshold must be in (0, 1), got {threshold!r}")
    t_out = transit_s(station, entry, model)
    usable = (100.0 - 100.0 * threshold) / model.drain_pct_s
    on_route = usable - model.takeoff_s - t_out
    if on_route <= 0:
        raise PlanError(f"a shift of {usable:.0f} s cannot even reach the route ({t_out:.0f} s)")
    back = t_out + model.land_s
    restore = station_model.restore_s(100.0 * threshold - back * model.drain_pct_s)
    cycle = model.takeoff_s + t_out + on_route + back + restore
    overlap = model.margin_s if overlap_s is None else overlap_s
    effective = max(on_route - overlap, 1e-9)
    needed = math.ceil(cycle / effective)
    upper = {1: min(1.0, on_route / cycle)}
    upper.update({n: min(1.0, n * effective / cycle) for n in range(2, max_drones + 1)})
    return CoverageBound(on_route, cycle, needed, upper)
