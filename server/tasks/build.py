"""Commands into tasks: the one table of which task class runs each DESIGN §4 ``action``."""

from __future__ import annotations

from drone.commands import (
    Command,
    Describe,
    Emergency,
    Goto,
    Hover,
    InvalidCommand,
    Land,
    Move,
    Patrol,
    ReturnHome,
    Search,
    Takeoff,
    Turn,
    Waypoints,
    parse_command,
)
from server.tasks.base import Task
from server.tasks.describe import DescribeTask
from server.tasks.errors import CommandError
from server.tasks.flight import EmergencyTask, HoverTask, LandTask, TakeoffTask
from server.tasks.goto import GotoMarkerTask
from server.tasks.home import ReturnHomeTask
from server.tasks.motion import MoveTask, TurnTask
from server.tasks.objects import FaceObjectTask, GotoObjectTask
from server.tasks.patrol import PatrolTask
from server.tasks.search import SearchTask
from server.tasks.waypoints import WaypointsTask


def build_task(command: object) -> Task:
    """The task for one DESIGN §4 command (a typed command or its JSON object).

    Raises:
        CommandError: not an object, no/unknown ``action``, or a malformed slot.
    """
    try:
        cmd = parse_command(command)
    except InvalidCommand as exc:
        raise CommandError(str(exc)) from None
    return task_for(cmd)


def task_for(cmd: Command) -> Task:
    """The task class that runs ``cmd``, one case per command type.

    Raises:
        CommandError: an action no task runs, or a slot the task needs is missing.
    """
    match cmd:
        case Takeoff():
            return TakeoffTask(cmd)
        case Land():
            return LandTask(cmd)
        case Emergency():
            return EmergencyTask(cmd)
        case Hover():
            return HoverTask(cmd)
        case Move():
            return MoveTask(cmd)
        case Turn(object=str()):
            return FaceObjectTask(cmd)
        case Turn():
            return TurnTask(cmd)
        case Goto(marker=None, object=str()):
            return GotoObjectTask(cmd)
        case Goto():
            return GotoMarkerTask(cmd)
        case Patrol():
            return PatrolTask(cmd)
        case ReturnHome():
            return ReturnHomeTask(cmd)
        case Search():
            return SearchTask(cmd)
        case Waypoints():
            return WaypointsTask(cmd)
        case Describe():
            return DescribeTask(cmd)
    raise CommandError(f"unknown action {cmd.action!r}")
