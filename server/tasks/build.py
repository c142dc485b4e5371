"""Commands into tasks: the one table of which task class runs each DESIGN §4 ``action``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from server.tasks.errors import CommandError
from server.tasks.objects import FaceObjectTask, GotoObjectTask
from server.tasks.types import (
    DescribeTask,
    EmergencyTask,
    GotoMarkerTask,
    HoverTask,
    LandTask,
    MoveTask,
    PatrolTask,
    ReturnHomeTask,
    SearchTask,
    TakeoffTask,
    Task,
    TurnTask,
    WaypointsTask,
)

TASK_TYPES: dict[str, type[Task]] = {
    "takeoff": TakeoffTask,
    "land": LandTask,
    "emergency": EmergencyTask,
    "hover": HoverTask,
    "move": MoveTask,
    "turn": TurnTask,
    "goto": GotoMarkerTask,
    "patrol": PatrolTask,
    "return_home": ReturnHomeTask,
    "search": SearchTask,
    "waypoints": WaypointsTask,
    "describe": DescribeTask,
}
"""Command ``action`` → task class. ``cancel`` and ``query`` are handled by the manager itself."""


def build_task(command: Any) -> Task:
    """The task for one DESIGN §4 command dict.

    Raises:
        CommandError: not a dict, no/unknown ``action``, or a malformed slot.
    """
    if not isinstance(command, Mapping):
        raise CommandError(f"a command must be an object, got {type(command).__name__}")
    action = command.get("action")
    cls = TASK_TYPES.get(action) if isinstance(action, str) else None
    if cls is None:
        raise CommandError(f"unknown action {action!r}")
    if action in ("goto", "turn") and "object" in command and "marker" not in command:
        cls = GotoObjectTask if action == "goto" else FaceObjectTask
    return cls(command)
