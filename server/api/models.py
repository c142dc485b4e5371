"""Request and response bodies of the REST API (``/api/v1``)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import FastAPI
from pydantic import BaseModel, ConfigDict, Field, WithJsonSchema

from drone.commands import COMMAND_ADAPTER
from drone.sim.battery import MAX_LEAK_PCT_S
from server.api.strict import StrictBody

COMMAND_SCHEMA_PREFIX = "Command"
"""OpenAPI component names of the command union: ``Command`` (the union) and ``CommandMove``,
``CommandTurn``, … (its members), apart from the REST bodies' own names."""

CommandList = Annotated[
    list[dict[str, Any]],
    WithJsonSchema(
        {"type": "array", "items": {"$ref": f"#/components/schemas/{COMMAND_SCHEMA_PREFIX}"}}
    ),
]
"""Commands as they travel (DESIGN §4's flat objects, in the grammar's key order), documented
as the typed union of drone/commands.py (:func:`add_command_schemas` puts it in /docs)."""


def command_schemas() -> dict[str, Any]:
    """The union's JSON schemas as OpenAPI components (``Command`` and one per member)."""
    prefix = COMMAND_SCHEMA_PREFIX
    schema = COMMAND_ADAPTER.json_schema(
        mode="serialization", ref_template=f"#/components/schemas/{prefix}{{model}}"
    )
    members = {f"{prefix}{name}": s for name, s in schema.pop("$defs").items()}
    return {prefix: schema, **members}


def add_command_schemas(app: FastAPI) -> None:
    """Make ``app.openapi()`` hold :func:`command_schemas` among its components."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        spec = generate()
        spec.setdefault("components", {}).setdefault("schemas", {}).update(command_schemas())
        return spec

    app.openapi = openapi  # type: ignore[method-assign]


# Wind a simulator fault may blow: well beyond what an AR.Drone survives (Beaufort 11,
# ~30 m/s), finite (a wind of [1e308, 1e308] is refused).
MAX_WIND_MPS = 30.0
WindComponent = Annotated[float, Field(ge=-MAX_WIND_MPS, le=MAX_WIND_MPS)]


class InterpretRequest(StrictBody):
    text: str = Field(max_length=2000)
    state: str | None = Field(default=None, description="dialog state whose grammars apply")


class InterpretResponse(BaseModel):
    text: str
    commands: CommandList


class CommandRequest(StrictBody):
    text: str = Field(max_length=2000)
    confidence: float = Field(default=1.0, ge=0.0, le=1.0)
    drone: str | None = None
    # Checked by the route (server.api.deps.Issued): a bad stamp refuses a motion command but
    # never holds a stop back.
    issued: float | None = Field(
        default=None,
        description="Unix seconds (server clock) when the operator gave it; default: arrival. "
        "A motion command that reaches the drone past the deadline is not flown.",
    )


class CommandResponse(BaseModel):
    reply: str
    commands: CommandList
    accepted: bool
    expects: str = Field(
        "", description="'confirm': the reply asks 'Did you say …?'; send yes or no next"
    )


class BusJoin(BaseModel):
    endpoint: str = Field(description="a router this console joins (--bus-connect)")
    joined: bool = Field(description="the link to it is up; false: dialled until it answers")
    since: float = Field(description="Unix time the link came up, went, or was first dialled")


class BusHealth(BaseModel):
    endpoints: list[str] = Field(description="where the router listens")
    alive: list[str] = Field(description="vehicles whose liveliness token is on the bus")
    client_config: str = Field(description="the observer's Zenoh client configuration file")
    joins: list[BusJoin] = Field(
        default_factory=list, description="the routers this console joins, each up or not"
    )


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    drones: dict[str, bool] = Field(description="drone name -> link up")
    captioner: str = Field(description="'ready' or why scene description is unavailable")
    bus: BusHealth | None = Field(
        default=None, description="the console's bus router (docs/bus.md); null: none runs"
    )


class FaultRequest(StrictBody):
    """A simulator fault (docs/flying.md, "Training"): ``link_loss`` (``duration_s``),
    ``battery`` (a cliff to ``battery_pct``), ``battery_drain`` (``drain_pct_s`` more per
    second), ``wind`` (``wind_mps``; with ``duration_s`` a gust), ``lost_markers``
    (``duration_s``) or ``clear``."""

    kind: Literal["link_loss", "battery", "battery_drain", "wind", "lost_markers", "clear"]
    duration_s: float | None = Field(default=None, ge=0, le=3600)
    battery_pct: float | None = Field(default=None, ge=0, le=100)
    drain_pct_s: float | None = Field(default=None, ge=0, le=MAX_LEAK_PCT_S)
    wind_mps: tuple[WindComponent, WindComponent] | None = None


class ActionBody(StrictBody):
    """Optional body of ``POST /drones/{id}/{action}``: a stop's id (the same on both roads
    from the page, so the vehicle runs it once) and when it was issued (unix seconds, the
    server's clock). Scripts may omit both."""

    id: str | None = Field(default=None, pattern=r"^[A-Za-z0-9_.:-]{1,64}$")
    issued: float | None = Field(default=None, ge=0, lt=1e11)


class ActionResult(BaseModel):
    drone: str
    action: str
    accepted: bool
    detail: str = ""
    # A stop with an id: when the vehicle ran it (unix s; None: not confirmed yet), the road
    # that brought it first (server or door), and how long after ``issued`` that was.
    id: str | None = None
    delivered: float | None = None
    road: str | None = None
    late_s: float | None = None


class DescribeResponse(BaseModel):
    drone: str
    text: str
    ms: float | None = None


# -- Responses of routes whose bodies come from a producer's dict (telemetry, the world, the
# fleet): the fields every answer holds are named and typed for /docs; anything more the
# producer writes (a MAVLink drone's extra telemetry, say) passes through unchanged. Routes
# answer with ``response_model_exclude_unset`` so nothing is added that the producer left out.

Num = int | float
"""A JSON number as the producer wrote it (an integer stays an integer on the wire)."""


class OpenResponse(BaseModel):
    """Named fields documented and checked; further fields passed through as they are."""

    model_config = ConfigDict(extra="allow")


class WorldInfo(OpenResponse):
    """``GET /world`` (drone/sim/world.py ``World.to_dict``): map frame, metres."""

    name: str
    kind: str = Field(description="indoor or outdoor")
    frame: str = Field(description="always 'map' (REP 103: x east, y north, z up)")
    bounds: dict[str, Num] = Field(description="x_min, x_max, y_min, y_max, z_min, z_max")
    markers: list[dict[str, Any]] = Field(description="id, dictionary, position, yaw, size_m")
    stations: list[dict[str, Any]] = Field(description="home and charging stations")


class VehicleProcessInfo(OpenResponse):
    """Where a drone runs in its own vehicle process: its link and its safety door."""

    mode: str
    connected: bool
    pid: int | None = None
    door_url: str | None = Field(default=None, description="the safety door, for this caller")
    door_ticket: str | None = Field(default=None, description="what opens it (pilots only)")
    age_s: float | None = None


class DroneInfo(OpenResponse):
    """``GET /drones/{id}``: the vehicle's snapshot (pose estimate, battery, control state,
    controller timing) plus these fields; ``vehicle`` for a drone in its own process."""

    name: str
    simulated: bool
    link_ok: bool | None = Field(description="None: not known yet (a replay before its navdata)")
    task: dict[str, Any] | None = Field(default=None, description="the running task")
    vehicle: VehicleProcessInfo | None = None


class SimTruth(OpenResponse):
    """``GET /sim/{id}/truth``: the simulator's true state (map frame, radians)."""

    name: str
    x: Num
    y: Num
    z: Num
    yaw_rad: Num
    battery_pct: Num


class FaultApplied(BaseModel):
    drone: str
    fault: str
    applied: bool


class FlightRow(OpenResponse):
    """One recorded flight (ISO 8601 UTC times); ``ended`` null while it is being recorded."""

    id: str
    started: str | None
    ended: str | None
    drones: list[str]
    bytes: int
    messages: int


class FlightList(BaseModel):
    flights: list[FlightRow]


class FlightDeleted(BaseModel):
    deleted: str


class SpeechStatus(BaseModel):
    """``GET /speech/status``: server recognition's state and the pool's load."""

    status: str
    model: str | None
    recognizer: str
    workers: int
    running: int
    waiting: int
    streams: int


BINARY = {"schema": {"type": "string", "format": "binary"}}
"""The OpenAPI schema of a body that is bytes (a file, audio, a camera stream)."""
