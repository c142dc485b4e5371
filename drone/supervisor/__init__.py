"""The vehicle's supervisor: the ANS safety monitors (battery, altitude, geofence, link,
estimator, navdata, jog limits, markers), acting on the drone and publishing typed alarms.

One module per monitor; :mod:`~drone.supervisor.core` runs them, :mod:`~drone.supervisor.build`
assembles a drone's. It imports nothing from ``server``: it runs in the vehicle process.
"""

from drone.supervisor.alarms import ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.build import SupervisorParams, default_monitors, keep_away_of, supervise
from drone.supervisor.core import Monitor, Supervisor
from drone.supervisor.phase import FLYING, Phase, phase_of

__all__ = [
    "FLYING",
    "ActionKind",
    "Alarm",
    "AlarmAction",
    "Monitor",
    "Phase",
    "Severity",
    "Supervisor",
    "SupervisorParams",
    "default_monitors",
    "keep_away_of",
    "phase_of",
    "supervise",
]
