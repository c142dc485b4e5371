"""The commands of DESIGN §4 as one typed, discriminated union: what the NLU understands and
what REST, the dialog and the task manager act on.

On the wire (REST JSON, rosbridge, MCAP, the page) a command stays a flat JSON object,
``action`` plus the slots the speaker stated; slots not stated are omitted (never ``null``).
:func:`parse_command` reads that object into a frozen model, :func:`wire` writes it back:
``wire(parse_command(obj)) == obj`` for every valid ``obj``. Numbers keep their JSON type (an
``int`` stays an ``int``), so a round trip leaves the bytes the page sees unchanged.

The union says what a command may carry, not what a task needs to run it: the NLU leaves out
what was not said ("turn 90 degrees" has no direction, "patrol" no markers), the dialog fills
conventions, and the task manager refuses what is still missing with a sentence. Slot values
are checked here (a direction is one of six words, a marker id an integer, a distance a finite
number): a bad one raises :class:`InvalidCommand` whose text names the slot.

Lives under ``drone/`` so that a vehicle process, which imports nothing from ``server/``, reads
the same commands.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from enum import StrEnum
from typing import Annotated, Any, Literal, TypeAlias, get_args

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

Direction = Literal["forward", "backward", "left", "right", "up", "down"]
Side = Literal["left", "right"]  # counter-clockwise is left (REP 103)
QueryItem = Literal["battery", "altitude", "position", "state"]
PatrolVerb = Literal["patrol_start", "patrol_pause", "patrol_resume", "patrol_stop"]
DIRECTIONS: tuple[Direction, ...] = get_args(Direction)
SIDES: tuple[Side, ...] = get_args(Side)
QUERY_ITEMS: tuple[QueryItem, ...] = get_args(QueryItem)
PATROL_CONTROLS: tuple[PatrolVerb, ...] = get_args(PatrolVerb)


class InvalidCommand(ValueError):
    """An object that is not a command of the union (unknown ``action``, a bad slot value).

    Its text is one sentence naming the action and slot, e.g. ``'move' needs 'direction'``.
    """


def _finite(value: Any, info: ValidationInfo) -> int | float:
    """A JSON number that is finite (NaN and infinities fly nowhere); ``True`` is no number."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"'{info.field_name}' must be a finite number, got {value!r}")
    return value


def _marker_id(value: Any) -> int:
    """A marker (or waypoint) number: an integer, never a string or a boolean."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"a marker id must be an integer, got {value!r}")
    return value


def _text(value: Any, info: ValidationInfo) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"'{info.field_name}' must be a non-empty string, got {value!r}")
    return value


Number = Annotated[int | float, BeforeValidator(_finite)]
"""Metres, degrees: finite, and an ``int`` stays an ``int`` on the wire."""
MarkerId = Annotated[int, BeforeValidator(_marker_id)]
Text = Annotated[str, BeforeValidator(_text)]


class _Frozen(BaseModel):
    """Common configuration: frozen, no fields beyond the model's own."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class _Command(_Frozen):
    """A member of the :data:`Command` union (each has its ``action``)."""


class Takeoff(_Command):
    action: Literal["takeoff"] = "takeoff"


class Land(_Command):
    action: Literal["land"] = "land"


class Hover(_Command):
    action: Literal["hover"] = "hover"


class Emergency(_Command):
    action: Literal["emergency"] = "emergency"


class ReturnHome(_Command):
    action: Literal["return_home"] = "return_home"


class Describe(_Command):
    action: Literal["describe"] = "describe"


class Cancel(_Command):
    action: Literal["cancel"] = "cancel"


class Help(_Command):
    action: Literal["help"] = "help"


class Search(_Command):
    """Turn in place until a marker is seen."""

    action: Literal["search"] = "search"


class Move(_Command):
    """A relative move in the drone's frame; ``distance`` in metres (unstated: the task's
    default)."""

    action: Literal["move"] = "move"
    direction: Direction | None = None
    distance: Number | None = None

    @field_validator("direction", mode="before")
    @classmethod
    def _direction(cls, value: Any) -> Any:
        if value is not None and value not in DIRECTIONS:
            raise ValueError(f"'move' needs 'direction' in {', '.join(DIRECTIONS)}; got {value!r}")
        return value


class Turn(_Command):
    """Turn in place (left = counter-clockwise) by ``angle`` degrees, or to face an object."""

    action: Literal["turn"] = "turn"
    direction: Side | None = None
    angle: Number | None = None
    object: Text | None = None
    colour: Text | None = None
    which: Text | None = None

    @field_validator("direction", mode="before")
    @classmethod
    def _direction(cls, value: Any) -> Any:
        if value is not None and value not in SIDES:
            raise ValueError(f"'turn' needs 'direction' left or right; got {value!r}")
        return value


class Goto(_Command):
    """Fly to a marker, a GPS world's numbered waypoint, or an object of the world."""

    action: Literal["goto"] = "goto"
    marker: MarkerId | None = None
    waypoint: MarkerId | None = None
    object: Text | None = None
    colour: Text | None = None
    which: Text | None = None


def _id_list(value: Any, info: ValidationInfo) -> Any:
    if value is not None and (not isinstance(value, list | tuple) or not value):
        raise ValueError(f"'patrol' needs '{info.field_name}', a non-empty list of marker ids")
    return value


IdList = Annotated[list[MarkerId], BeforeValidator(_id_list)]


class Patrol(_Command):
    """Visit ``markers`` (or a GPS world's ``waypoints``) in order, round and round; neither:
    every marker (the dialog's convention)."""

    action: Literal["patrol"] = "patrol"
    markers: IdList | None = None
    waypoints: IdList | None = None


class PatrolControl(_Command):
    """The fleet's patrol of the world's route: start, pause, resume or stop it."""

    action: PatrolVerb


class Query(_Command):
    """A question answered from telemetry."""

    action: Literal["query"] = "query"
    item: QueryItem | None = None

    @field_validator("item", mode="before")
    @classmethod
    def _item(cls, value: Any) -> Any:
        if value is not None and value not in QUERY_ITEMS:
            raise ValueError(f"'query' needs 'item' in {', '.join(QUERY_ITEMS)}; got {value!r}")
        return value


class Choose(_Command):
    """An answer to "Which chair?": the nearest, the red one, the north one."""

    action: Literal["choose"] = "choose"
    which: Text | None = None
    colour: Text | None = None
    object: Text | None = None


class Waypoint(_Frozen):
    """One point of a :class:`Waypoints` flight: map frame ``x, y`` (``z`` optional) or
    geodetic ``lat, lon`` (``alt`` optional), with an optional own heading ``yaw_deg``."""

    x: Number | None = None
    y: Number | None = None
    z: Number | None = None
    lat: Number | None = None
    lon: Number | None = None
    alt: Number | None = None
    yaw_deg: Number | None = None

    @model_validator(mode="after")
    def _where(self) -> Waypoint:
        if self.lat is not None or self.lon is not None or self.alt is not None:
            for key in ("lat", "lon"):
                if getattr(self, key) is None:
                    raise ValueError(f"a lat/lon waypoint needs '{key}'")
        else:
            for key in ("x", "y"):
                if getattr(self, key) is None:
                    raise ValueError(f"a waypoint needs '{key}' (or 'lat' and 'lon')")
        return self


def _waypoint_list(value: Any) -> Any:
    if not isinstance(value, list | tuple) or not value:
        raise ValueError("'waypoints' needs a non-empty list of waypoints")
    for i, w in enumerate(value):
        if not isinstance(w, Mapping | Waypoint):
            raise ValueError(f"waypoint {i} must be an object, got {w!r}")
    return value


class Waypoints(_Command):
    """Fly map-frame or geodetic points in order (the fleet's plans); ``loop`` round and
    round, arrival within ``tolerance_m``, heading ``yaw_deg`` unless a point has its own."""

    action: Literal["waypoints"] = "waypoints"
    waypoints: Annotated[list[Waypoint], BeforeValidator(_waypoint_list)]
    loop: bool | None = None
    tolerance_m: Number | None = None
    yaw_deg: Number | None = None


Command: TypeAlias = Annotated[
    Takeoff
    | Land
    | Hover
    | Emergency
    | ReturnHome
    | Describe
    | Cancel
    | Help
    | Search
    | Move
    | Turn
    | Goto
    | Patrol
    | PatrolControl
    | Query
    | Choose
    | Waypoints,
    Field(discriminator="action"),
]
"""One command of DESIGN §4, told apart by its ``action``."""

COMMAND_ADAPTER: TypeAdapter[Command] = TypeAdapter(Command)
ACTIONS: frozenset[str] = frozenset(COMMAND_ADAPTER.json_schema()["discriminator"]["mapping"])
"""Every ``action`` the union holds."""


class DirectAction(StrEnum):
    """What a button, a key or ``POST /drones/{id}/{action}`` does to a drone directly.

    ``reset`` clears an AR.Drone's emergency state; it is no spoken command.
    """

    TAKEOFF = "takeoff"
    LAND = "land"
    HOVER = "hover"
    EMERGENCY = "emergency"
    RESET = "reset"


def parse_command(obj: object) -> Command:
    """The command ``obj`` (a JSON object, or already a command) stands for.

    Raises:
        InvalidCommand: not an object, no or unknown ``action``, a slot that is not the
            action's, or a slot value that is wrong (the text names it).
    """
    if isinstance(obj, _Command):
        return obj  # type: ignore[return-value]
    if not isinstance(obj, Mapping):
        raise InvalidCommand(f"a command must be an object, got {type(obj).__name__}")
    action = obj.get("action")
    if not isinstance(action, str) or action not in ACTIONS:
        raise InvalidCommand(f"unknown action {action!r}")
    try:
        return COMMAND_ADAPTER.validate_python(dict(obj))
    except ValidationError as exc:
        raise InvalidCommand(_reason(action, exc)) from None


def wire(command: Command) -> dict[str, Any]:
    """``command`` as the flat JSON object of DESIGN §4 (unstated slots omitted)."""
    return command.model_dump(exclude_none=True)


def _reason(action: str, exc: ValidationError) -> str:
    """The first error of ``exc`` as one sentence about ``action``'s slot."""
    err = exc.errors(include_url=False)[0]
    # The union's tag comes first in the location: ("move", "distance") or, for a waypoint,
    # ("waypoints", "waypoints", 0, "x").
    loc = [str(p) for p in err["loc"][1:]]
    slot = loc[0] if loc else ""
    if err["type"] == "value_error":
        return str(err["ctx"]["error"])
    if err["type"] == "missing":
        return f"'{action}' needs '{slot}'"
    if err["type"] == "extra_forbidden":
        return f"'{action}' has no slot '{'.'.join(loc)}'"
    return f"'{action}' slot '{'.'.join(loc)}': {err['msg']}"


__all__ = [
    "ACTIONS",
    "COMMAND_ADAPTER",
    "DIRECTIONS",
    "QUERY_ITEMS",
    "SIDES",
    "Cancel",
    "Choose",
    "Command",
    "Describe",
    "DirectAction",
    "Emergency",
    "Goto",
    "Help",
    "Hover",
    "InvalidCommand",
    "Land",
    "Move",
    "Patrol",
    "PatrolControl",
    "Query",
    "ReturnHome",
    "Search",
    "Takeoff",
    "Turn",
    "Waypoint",
    "Waypoints",
    "parse_command",
    "wire",
]
