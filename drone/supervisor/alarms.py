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


class BadAlarm(ValueError):
    """An alarm message that is not one (:meth:`Alarm.from_message`); the text says why."""


@dataclass(frozen=True)
class AlarmAction:
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

    @classmethod
    def from_command(cls, command: dict[str, Any]) -> AlarmAction:
        """The action :meth:`command` made ``command`` of.

        Raises:
            BadAlarm: a command no supervisor action gives.
        """
        action = command.get("action")
        try:
            if action == "move" and command.get("direction") == "down":
                return cls(ActionKind.DESCEND, distance_m=float(command["distance"]))
            if action == "waypoints":
                (point,) = command["waypoints"]
                return cls(
                    ActionKind.BACK_OFF,
                    to=(float(point["x"]), float(point["y"]), float(point["z"])),
                )
            return cls(ActionKind(str(action)))
        except (KeyError, TypeError, ValueError) as exc:
            raise BadAlarm(f"no supervisor action is {command!r}") from exc

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
    action: AlarmAction | None = None

    def as_message(self, drone: str = "") -> dict[str, Any]:
        """JSON-ready, for the graph and the bus."""
        return {
            "drone": drone,
            "monitor": self.monitor,
            "severity": self.severity.value,
            "text": self.text,
            "action": self.action.command() if self.action is not None else None,
        }

    @classmethod
    def from_message(cls, msg: object) -> Alarm:
        """The alarm :meth:`as_message` wrote (a vehicle's, read by its console).

        Raises:
            BadAlarm: not an alarm message (the text names what is wrong).
        """
        if not isinstance(msg, dict):
            raise BadAlarm("an alarm message is a JSON object")
        monitor, text, action = msg.get("monitor"), msg.get("text"), msg.get("action")
        if not isinstance(monitor, str) or not monitor or not isinstance(text, str):
            raise BadAlarm("an alarm names its monitor and says its text")
        try:
            severity = Severity(str(msg.get("severity")))
        except ValueError as exc:
            raise BadAlarm(f"unknown severity {msg.get('severity')!r}") from exc
        if action is not None and not isinstance(action, dict):
            raise BadAlarm("an alarm's action is a command object or null")
        return cls(
            monitor,
            severity,
            text,
            AlarmAction.from_command(action) if action is not None else None,
        )
