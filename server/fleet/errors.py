"""Errors of the fleet package (CTM, LTM, planner, geodesy, vehicle client).

FleetError
├── GeoError          a latitude/longitude/altitude out of range or not finite
├── MessageError      a status, flight plan or mission that does not parse (field named)
├── MissionError      a mission that cannot be flown (no route, bad threshold, unknown marker)
├── PlanError         planner inputs that make no sense (negative speed, threshold ≥ 1)
├── NotFoundError     no such mission or drone
├── IllegalTransition a mission state change the table in states.py forbids (resume a running
│                     mission, end an ended one)
└── ClientError       the ``vehicle`` client cannot reach or talk to the central server
"""

from __future__ import annotations


class FleetError(Exception):
    """Base of every fleet error."""


class GeoError(FleetError, ValueError):
    pass


class MessageError(FleetError, ValueError):
    pass


class MissionError(FleetError, ValueError):
    pass


class PlanError(FleetError, ValueError):
    pass


class NotFoundError(FleetError, KeyError):
    def __str__(self) -> str:  # KeyError quotes its argument; keep the plain message
        return str(self.args[0]) if self.args else ""


class IllegalTransition(FleetError, RuntimeError):
    pass


class ClientError(FleetError):
    pass
