"""Request and response bodies of the REST API (``/api/v1``)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class InterpretRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    text: str = Field(max_length=2000)
    state: str | None = Field(default=None, description="dialog state whose grammars apply")


class InterpretResponse(BaseModel):
    text: str
    commands: list[dict[str, Any]]


class CommandRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    text: str = Field(max_length=2000)
    confidence: float = Field(default=1.0, ge=0.0, le=1.0)
    drone: str | None = None


class CommandResponse(BaseModel):
    reply: str
    commands: list[dict[str, Any]]
    accepted: bool


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    drones: dict[str, bool] = Field(description="drone name -> link up")
    captioner: str = Field(description="'ready' or why scene description is unavailable")


class FaultRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["link_loss", "battery", "wind", "clear"]
    duration_s: float | None = Field(default=None, ge=0, le=3600)
    battery_pct: float | None = Field(default=None, ge=0, le=100)
    wind_mps: tuple[float, float] | None = None


class ActionResult(BaseModel):
    drone: str
    action: str
    accepted: bool
    detail: str = ""


class Describe(BaseModel):
    drone: str
    text: str
    ms: float | None = None
