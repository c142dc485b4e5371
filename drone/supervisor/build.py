"""The supervisor of one drone, built alike wherever the drone's stack is built."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from drone.supervisor.altitude import AltitudeMonitor, ceiling_of
from drone.supervisor.battery import BatteryMonitor
from drone.supervisor.core import Executor, Monitor, Supervisor, act_on, executor_phase
from drone.supervisor.estimator import EstimatorMonitor, SensorAgreementMonitor
from drone.supervisor.geofence import GeofenceMonitor
from drone.supervisor.jog import JogLimitMonitor
from drone.supervisor.link import LinkMonitor
from drone.supervisor.markers import MarkersLostMonitor
from drone.supervisor.navdata import NavdataMonitor
from drone.supervisor.people import KeepAway, KeepAwayMonitor, Person
from drone.supervisor.temperature import LAND_C, WARN_C, TemperatureMonitor
from drone.vehicle import Vehicle


@dataclass(frozen=True)
class SupervisorParams:
    """The thresholds the supervisor reads (names as in ``server.settings.Settings``)."""

    battery_low_pct: float = 25.0
    battery_critical_pct: float = 12.0
    altitude_ceiling_m: float | None = None  # None: the world's (drone/limits.py)
    ans_period_s: float = 0.5
    search_after_s: float = 1.5
    temperature_warn_c: float = WARN_C
    temperature_land_c: float = LAND_C

    @classmethod
    def from_settings(cls, settings: Any) -> SupervisorParams:
        names = cls.__dataclass_fields__
        return cls(**{n: getattr(settings, n) for n in names if hasattr(settings, n)})


def default_monitors(params: SupervisorParams, world: Any) -> list[Monitor]:
    """Every monitor for a drone in ``world`` (the geofence only when the world has bounds)."""
    p = params
    fast = min(p.ans_period_s, 0.25)
    out: list[Monitor] = [
        BatteryMonitor(p.battery_low_pct, p.battery_critical_pct, period_s=p.ans_period_s),
        AltitudeMonitor(ceiling_of(p.altitude_ceiling_m, world), period_s=p.ans_period_s),
        LinkMonitor(period_s=fast),
        MarkersLostMonitor(p.search_after_s, period_s=p.ans_period_s),
        EstimatorMonitor(period_s=p.ans_period_s),
        NavdataMonitor(fast),
    ]
    b = getattr(world, "bounds", None)
    if b is not None:
        out.append(GeofenceMonitor(b.x_min, b.x_max, b.y_min, b.y_max, period_s=fast))
    out += [
        SensorAgreementMonitor(period_s=fast),
        JogLimitMonitor(period_s=fast),
        TemperatureMonitor(p.temperature_warn_c, p.temperature_land_c, period_s=p.ans_period_s),
    ]
    return out


def keep_away_of(world: Any, people: Callable[[], Sequence[Person]]) -> KeepAway:
    """The world's keep-away from people (``limits.person_distance_m``), ``people`` tracked."""
    from drone.limits import limits_of

    lim = limits_of(world)
    return KeepAway(people, lim.person_distance_m, lim)


def supervise(
    vehicle: Vehicle,
    executor: Executor,
    world: Any,
    params: Any = None,
    *,
    keep_away: KeepAway | None = None,
) -> Supervisor:
    """The supervisor of ``vehicle`` acting through ``executor`` (its task executor);
    ``params``: a :class:`SupervisorParams` or a ``Settings`` (None: the defaults);
    ``keep_away``: where people are tracked (:func:`keep_away_of`), the keep-away monitor."""
    if not isinstance(params, SupervisorParams):
        params = SupervisorParams() if params is None else SupervisorParams.from_settings(params)
    monitors = default_monitors(params, world)
    if keep_away is not None and keep_away.distance_m > 0.0:
        monitors.append(KeepAwayMonitor(keep_away, period_s=min(params.ans_period_s, 0.25)))
    return Supervisor(
        monitors,
        vehicle.snapshot,
        executor_phase(executor),
        act_on(executor),
    )
