"""Errors of the vehicle processes and the console's side of them.

::

    VehicleError
    ├── CannotStart           the vehicle cannot start here (e.g. its simulator's address is
    │                         taken): starting it again would fail the same way
    ├── VehicleKeyError       a vehicle key or its name is missing, unreadable or malformed
    ├── RemoteCallError       a call over the link was refused or not answered
    │   └── VehicleUnavailable    the drone's vehicle process is not on the link (REST: 503)
    ├── NoBus                 the console's bus did not start: its vehicle processes, which
    │                         join it over the bus, cannot be spawned
    ├── CommandExpired        the vehicle did not run a sentence: it came past its deadline
    └── DoorError             the safety door (server.vehicles.door)
        ├── DoorProtocolError     a frame the door protocol refuses (bad JSON, op, field)
        └── TicketError           a door ticket that is malformed, forged, expired or not ours
"""

from __future__ import annotations

from typing import Any


class VehicleError(Exception):
    """Base of this package's errors."""


class CannotStart(VehicleError):
    """The vehicle cannot start here; the message says why and what to change."""


class VehicleKeyError(VehicleError):
    """A vehicle key (or the vehicle name it is for) is missing, unreadable or malformed; the
    message says which and how to make one."""


class RemoteCallError(VehicleError):
    """A command to a vehicle was refused, failed or timed out."""


class VehicleUnavailable(RemoteCallError):
    """The drone's vehicle process is not on the bus: not joined yet (starting, restarting),
    gone, or silent. REST answers 503 with this message, the drone and ``Retry-After``."""

    def __init__(self, message: str, *, drone: str | None = None, retry_after_s: int = 2) -> None:
        super().__init__(message)
        self.drone = drone
        self.retry_after_s = retry_after_s


class NoBus(VehicleError):
    """The console's bus router did not start, and it has vehicle processes to spawn, which
    reach it only over the bus; the message says why and what to change."""


class CommandExpired(VehicleError):
    """The vehicle judged a sentence's commands past their deadline as it received them and ran
    none of them; ``age_s`` and ``deadline_s`` as it judged, ``commands`` what was not run."""

    def __init__(
        self, message: str, *, age_s: float, deadline_s: float, commands: list[dict[str, Any]]
    ) -> None:
        super().__init__(message)
        self.age_s = age_s
        self.deadline_s = deadline_s
        self.commands = commands


class DoorError(VehicleError):
    """Base of the safety door's errors."""


class DoorProtocolError(DoorError):
    """A frame that is not a message of the door protocol; the message says what is wrong."""


class TicketError(DoorError):
    """A door ticket that cannot be used: malformed, forged, expired, or for another drone."""
