"""Request and response bodies of the REST API (``/api/v1``)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field

from drone.sim.battery import MAX_LEAK_PCT_S
from server.api.strict import StrictBody

# Wind a simulator fault may blow: well beyond what an AR.Drone survives (Beaufort 11,
# ~30 m/s), finite (issue 14: [1e308, 1e308] was accepted).
MAX_WIND_MPS = 30.0
WindComponent = Annotated[float, Field(ge=-MAX_WIND_MPS, le=MAX_WIND_MPS)]


class InterpretRequest(StrictBody):
    text: str = Field(max_length=2000)
    state: str | None = Field(default=None, description="dialog state whose grammars apply")


class InterpretResponse(BaseModel):
    text: str
    commands: list[dict[str, Any]]


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
    commands: list[dict[str, Any]]
    accepted: bool
    expects: str = Field(
        "", description="'confirm': the reply asks 'Did you say …?'; send yes or no next"
    )


class BusHealth(BaseModel):
    endpoints: list[str] = Field(description="where the router listens")
    alive: list[str] = Field(description="vehicles whose liveliness token is on the bus")
    client_config: str = Field(description="the observer's Zenoh client configuration file")


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


class Describe(BaseModel):
    drone: str
    text: str
    ms: float | None = None
