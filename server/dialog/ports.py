"""What the dialog manager needs from the task manager, the vehicle and the captioner.

Typing protocols ("ports"): the real TaskManager / Vehicle / captioner service satisfy them
directly or through a thin adapter; tests use small in-memory fakes that behave like them.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

Command = Mapping[str, Any]


@dataclass(frozen=True)
class DroneView:
    """What the dialog reads about the drone at one instant (the supervisor reads the vehicle's
    own :class:`drone.vehicle.VehicleSnapshot`)."""

    battery_pct: float
    altitude_m: float
    flying: bool
    link_ok: bool = True
    x_m: float = 0.0
    y_m: float = 0.0
    yaw_deg: float = 0.0
    visible_markers: tuple[int, ...] = ()
    ctrl_state: str = ""
    emergency: bool = False  # navdata state bit 31: motors cut until a reset
    battery_known: bool = True  # False until navdata carries a battery reading
    navdata_doubt: str = ""  # why the driver doubts the navdata ("" while it trusts it)


@dataclass(frozen=True)
class TaskDecision:
    """The task manager's answer to one submitted command."""

    accepted: bool
    reason: str = ""
    question: bool = False  # the reason is a question; the next answer fills the command


@dataclass(frozen=True)
class TaskReport:
    """Something the task manager reports: kind is one of
    started, took_off, landed, landing, done, failed, idle, marker_lost, marker_found."""

    kind: str
    command: Mapping[str, Any] = field(default_factory=dict)
    detail: str = ""


class TaskPort(Protocol):
    def submit(
        self, commands: Sequence[Command]
    ) -> Sequence[TaskDecision] | Awaitable[Sequence[TaskDecision]]:
        """Queue ``commands`` in order; one decision per command (a task manager in another
        process answers with an awaitable)."""
        ...

    def cancel(self) -> None:
        """Drop every queued and running voluntary task (the drone hovers)."""
        ...

    def preempt(self, command: Command, by: str = "") -> None:
        """Drop the queue and run ``command`` now (land, hover, emergency, ANS actions);
        ``by`` names the safety monitor that acted ("" for the operator)."""
        ...

    def on_event(self, callback: Callable[[TaskReport], None]) -> None:
        """Call ``callback`` for every task event."""
        ...


class VehiclePort(Protocol):
    def snapshot(self) -> DroneView: ...

    def marker_ids(self) -> frozenset[int]:
        """Ids of the markers of the world (empty when unknown: then any id is accepted)."""
        ...


class FleetReply(Protocol):
    @property
    def ok(self) -> bool: ...

    @property
    def text(self) -> str: ...


class FleetPort(Protocol):
    """The Central patrol (``server.fleet.central.CentralPatrol``): voice's way to the CTM.

    A vehicle process reaches it over the link: its answers are awaitables. ``stop`` answers
    ``ok`` False when no patrol runs (the dialog then stops the drone's own task); a port in
    this process also has ``running()``, asked first. ``pause`` and ``resume`` pause and
    resume the patrol (server.fleet.states)."""

    def start(self, threshold: float = ...) -> FleetReply | Awaitable[FleetReply]: ...

    def stop(self) -> FleetReply | Awaitable[FleetReply]: ...

    def pause(self) -> FleetReply | Awaitable[FleetReply]: ...

    def resume(self) -> FleetReply | Awaitable[FleetReply]: ...


class DescribePort(Protocol):
    async def describe(self) -> str:
        """One sentence describing the current camera image."""
        ...
