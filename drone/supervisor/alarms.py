"""What the supervisor publishes: typed alarms, each naming its monitor, its severity, what it
says to the operator and the action the vehicle took (if any)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any


class Severity(StrEnum):
    """How loud the dialog says it (the ``level`` of ``/console/reply``)."""

    INFO = "info"
    WARN = "warn"
    ALERT = "alert"


class ActionKind(StrEnum):
    """What the supervisor makes the drone do (PX4 commander's failsafe actions, cut to ours)."""

    HOVER = "hover"
    LAND = "land"
    RETURN_HOME = "return_home"
    DESCEND = "descend"  # down by ``distance_m``, under the ceiling
    BACK_OFF = "back_off"  # fly to ``to`` (map frame), away from a person


# Safety actions the task executor runs at once, bypassing its queue (TaskManager.preempt).
PREEMPTING = (ActionKind.HOVER, ActionKind.LAND, ActionKind.RETURN_HOME)


@dataclass(frozen=True)
class Action:
    """One action the supervisor took; :meth:`command` is it as a DESIGN §4 command."""

    kind: ActionKind
    distance_m: float = 0.0  # DESCEND
    to: tuple[float, float, float] | None = None  # BACK_OFF: x, y, z in metres, map frame

    def command(self) -> dict[str, Any]:
        """The command the task executor runs (and the audit log records)."""
        if self.kind is ActionKind.DESCEND:
            return {"action": "move", "direction": "down", "distance": self.distance_m}
        if self.kind is ActionKind.BACK_OFF:
            assert self.to is not None
            x, y, z = self.to
            return {"action": "waypoints", "waypoints": [{"x": x, "y": y, "z": z}]}
        return {"action": self.kind.value}

    @property
    def event(self) -> str:
        """The dialog's state-machine event this action is (a descent or back-off is a move)."""
        return "move" if self.kind in (ActionKind.DESCEND, ActionKind.BACK_OFF) else self.kind


@dataclass(frozen=True)
class Alarm:
    """One alarm: ``monitor`` names what raised it (its id on the wire and on the reply)."""

    monitor: str
    severity: Severity
    text: str
    action: Action | None = None

    def as_message(self, drone: str = "") -> dict[str, Any]:
        """JSON-ready, for the graph and the bus."""
        return {
            "drone": drone,
            "monitor": self.monitor,
            "severity": self.severity.value,
            "text": self.text,
            "action": self.action.command() if self.action is not None else None,
        }
