"""What the dialog manager needs from the task manager, the vehicle and the captioner.

Typing protocols ("ports"): the real TaskManager / Vehicle / captioner service satisfy them
directly or through a thin adapter; tests use small in-memory fakes that behave like them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

Command = Mapping[str, Any]


@dataclass(frozen=True)
class VehicleSnapshot:
    """What the dialog and the ANS read about the drone at one instant."""

    battery_pct: float
    altitude_m: float
    flying: bool
    link_ok: bool = True
    x_m: float = 0.0
    y_m: float = 0.0
    yaw_deg: float = 0.0
    visible_markers: tuple[int, ...] = ()
    ctrl_state: str = ""


@dataclass(frozen=True)
class TaskDecision:
    """The task manager's answer to one submitted command."""

    accepted: bool
    reason: str = ""


@dataclass(frozen=True)
class TaskEvent:
    """Something the task manager reports: kind is one of
    started, took_off, landed, landing, done, failed, idle, marker_lost, marker_found."""

    kind: str
    command: Mapping[str, Any] = field(default_factory=dict)
    detail: str = ""


class TaskPort(Protocol):
    def submit(self, commands: Sequence[Command]) -> Sequence[TaskDecision]:
        """Queue ``commands`` in order; one decision per command."""
        ...

    def cancel(self) -> None:
        """Drop every queued and running voluntary task (the drone hovers)."""
        ...

    def preempt(self, command: Command) -> None:
        """Drop the queue and run ``command`` now (land, hover, emergency, ANS actions)."""
        ...

    def on_event(self, callback: Callable[[TaskEvent], None]) -> None:
        """Call ``callback`` for every task event."""
        ...


class VehiclePort(Protocol):
    def snapshot(self) -> VehicleSnapshot: ...

    def marker_ids(self) -> frozenset[int]:
        """Ids of the markers of the world (empty when unknown: then any id is accepted)."""
        ...


class DescribePort(Protocol):
    async def describe(self) -> str:
        """One sentence describing the current camera image."""
        ...
