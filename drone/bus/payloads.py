"""Payloads on the bus: versioned JSON, decoded into frozen models or refused with a reason."""

from __future__ import annotations

import json
import math
import struct
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from drone.bus.errors import PayloadError

MAX_PAYLOAD_BYTES = 64 * 1024


class Telemetry(BaseModel):
    """``uavc/<fleet>/<drone>/telemetry`` (schema 1): where a drone is and how it fares."""

    model_config = ConfigDict(frozen=True, extra="ignore")

    v: Literal[1] = 1
    drone: str
    stamp: float  # Unix seconds, the vehicle's clock
    x: float  # metres, map frame (docs/CONVENTIONS.md)
    y: float
    z: float
    yaw_deg: float
    battery_pct: float
    state: str  # the vehicle's flight state (LANDED, FLYING, HOVERING, …)
    link_ok: bool = True
    flying: bool = False

    @field_validator("stamp", "x", "y", "z", "yaw_deg", "battery_pct")
    @classmethod
    def _finite(cls, value: float) -> float:
        if not math.isfinite(value):
            raise ValueError("must be a finite number")
        return value


class Status(BaseModel):
    """``uavc/<fleet>/<drone>/status`` (schema 1, 1 Hz): what a drone is doing and who
    commands it."""

    model_config = ConfigDict(frozen=True, extra="ignore")

    v: Literal[1] = 1
    drone: str
    stamp: float  # Unix seconds, the vehicle's clock
    mode: str  # the flight state (LANDED, FLYING, HOVERING, …)
    task: str = ""  # the task it runs ("" when idle)
    alarms: list[str] = Field(default_factory=list)  # the supervisor's live alarms
    lease: str | None = None  # the pilot lease's holder (pilot@console), None when free
    simulated: bool = True
    # the JSON of ``GET /api/v1/drones/{id}`` as the vehicle answers it
    detail: dict[str, Any] = Field(default_factory=dict)

    @field_validator("stamp")
    @classmethod
    def _finite_stamp(cls, value: float) -> float:
        if not math.isfinite(value):
            raise ValueError("must be a finite number")
        return value


def encode(message: BaseModel) -> bytes:
    return message.model_dump_json().encode()


def decode_telemetry(data: bytes) -> Telemetry:
    """Decode one telemetry payload.

    Raises:
        PayloadError: over 64 KB, not JSON, or not the schema (the reason names the field).
    """
    if len(data) > MAX_PAYLOAD_BYTES:
        raise PayloadError(f"telemetry payload of {len(data)} bytes (at most {MAX_PAYLOAD_BYTES})")
    try:
        raw = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PayloadError(f"telemetry is not JSON: {exc}") from exc
    try:
        return Telemetry.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "payload"
        raise PayloadError(f"telemetry {where}: {first['msg']}") from exc


def decode_status(data: bytes) -> Status:
    """Decode one status payload.

    Raises:
        PayloadError: over 64 KB, not JSON, or not the schema.
    """
    if len(data) > MAX_PAYLOAD_BYTES:
        raise PayloadError(f"status payload of {len(data)} bytes (at most {MAX_PAYLOAD_BYTES})")
    try:
        raw = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PayloadError(f"status is not JSON: {exc}") from exc
    try:
        return Status.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "payload"
        raise PayloadError(f"status {where}: {first['msg']}") from exc


# A camera frame's attachment: when the vehicle made the JPEG, Unix seconds on the vehicle's
# clock, as one little-endian IEEE 754 double (the frame itself stays the bare JPEG).
_STAMP = struct.Struct("<d")


def encode_camera_stamp(stamp: float) -> bytes:
    """The attachment of a camera frame made at ``stamp`` (Unix seconds)."""
    return _STAMP.pack(stamp)


def decode_camera_stamp(data: bytes | None) -> float | None:
    """The stamp of a camera frame's attachment; None when there is none or it is not one
    (a frame without a stamp is shown with the time it arrived)."""
    if data is None or len(data) != _STAMP.size:
        return None
    (stamp,) = _STAMP.unpack(data)
    return stamp if math.isfinite(stamp) and stamp > 0 else None
