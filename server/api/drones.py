"""Drones: telemetry, direct actions (take off, land, hover, emergency, reset), describe, video."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, Body, HTTPException, Path, Request
from fastapi.responses import StreamingResponse

from drone.commands import DirectAction
from server.api.deps import DroneDep, IssuedDep, PilotDep, RoleDep, RuntimeDep, check_lease
from server.api.models import BINARY, ActionBody, ActionResult, DescribeResponse, DroneInfo
from server.runtime import Runtime
from server.vehicles.direct_actions import command_source, perform_async, perform_stop_async
from server.vehicles.door import advertised_url
from server.vehicles.door_protocol import STOP_ACTIONS

router = APIRouter(prefix="/drones", tags=["drones"])

MJPEG_BOUNDARY = "frame"


def _for_caller(
    out: dict[str, Any], request: Request, runtime: Runtime, role: str
) -> dict[str, Any]:
    """A vehicle process's ``door_url`` as this caller can open it (the host it reached us
    by: a phone on the LAN gets the LAN address, not the vehicle's loopback or wildcard), and
    for a pilot a ``door_ticket`` that opens it (also while this server is down)."""
    vehicle = out.get("vehicle")
    if isinstance(vehicle, dict) and vehicle.get("door_url"):
        vehicle["door_url"] = advertised_url(vehicle["door_url"], request.headers.get("host"))
        name = str(out.get("name", ""))
        vehicle["door_ticket"] = runtime.vehicles.door_ticket(name) if role == "pilot" else None
    return out


@router.get("", response_model=list[DroneInfo], response_model_exclude_unset=True)
def list_drones(request: Request, runtime: RuntimeDep, role: RoleDep) -> list[dict[str, Any]]:
    """Every drone with its telemetry, state, task and link."""
    return [
        _for_caller(stack.telemetry(), request, runtime, role) for stack in runtime.drones.values()
    ]


@router.get("/{drone_id}", response_model=DroneInfo, response_model_exclude_unset=True)
def get_drone(
    request: Request, stack: DroneDep, runtime: RuntimeDep, role: RoleDep
) -> dict[str, Any]:
    """One drone: telemetry, pose estimate, control state, task, link and controller timing.

    ``vehicle.door_url`` (a drone in its own process): its safety door, at the host this
    request named: a WebSocket for emergency, land and hover that no web traffic can delay
    (docs/safety-door.md); ``vehicle.door_ticket`` (pilots): what opens it."""
    return _for_caller(stack.telemetry(), request, runtime, role)


@router.post("/{drone_id}/describe", response_model=DescribeResponse)
async def describe(stack: DroneDep, runtime: RuntimeDep, _role: RoleDep) -> DescribeResponse:
    """Caption the latest camera frame with the ONNX captioner (503 when it is unavailable)."""
    status = runtime.captioner_status()
    if status != "ready":
        raise HTTPException(status_code=503, detail=status)
    text, ms = await runtime.describe(stack.name)
    return DescribeResponse(drone=stack.name, text=text, ms=ms)


@router.post("/{drone_id}/{action}", response_model=ActionResult)
async def act(
    which: Annotated[DirectAction, Path(alias="action")],
    request: Request,
    stack: DroneDep,
    runtime: RuntimeDep,
    _role: PilotDep,
    issued: IssuedDep,
    body: Annotated[ActionBody | None, Body()] = None,
) -> ActionResult:
    """Direct control; land, hover and emergency reach the wire ahead of anything queued.

    Anything but land, emergency and hover needs the pilot lease to be free (409 otherwise).
    A take-off the drone cannot do now is not sent: ``accepted: false`` and ``detail`` says why
    and what to do. ``X-Command-Source`` (button, keyboard, map) is recorded in the audit log.
    ``X-Command-Issued`` (or a JSON body's ``issued``): Unix seconds when the operator gave
    it; a take-off or reset that reaches the drone more than ``command_deadline_s`` later is
    not sent (``accepted: false``, "Not flown: …"); a stop never expires, and a bad stamp
    (422 for the others) never holds it back.

    A stop may carry ``{"id", "issued"}`` (the page sends both roads one id): the drone runs it
    once, whichever road brings it first, and not at all if the operator superseded it on the
    safety door; the answer says when it ran (``delivered``), by which ``road``, and ``late_s``
    after ``issued``. ``delivered`` null: sent, not confirmed yet (try again with the same id).
    """
    action = which.value
    check_lease(request, runtime, {action})
    source = command_source(request.headers.get("x-command-source"))
    if action in STOP_ACTIONS and body is not None and body.id is not None:
        verdict = await perform_stop_async(
            stack,
            runtime.dialogs.get(stack.name),
            runtime.audit,
            action,
            body.id,
            body.issued if body.issued is not None else issued.of([action]),
            source=source,
            battery_low_pct=runtime.settings.battery_low_pct,
        )
        return ActionResult(
            drone=stack.name,
            action=action,
            accepted=verdict.accepted,
            detail=verdict.detail,
            id=body.id,
            delivered=verdict.delivered,
            road=verdict.road,
            late_s=verdict.late_s,
        )
    out = await perform_async(
        stack,
        runtime.dialogs.get(stack.name),
        runtime.audit,
        action,
        source=source,
        battery_low_pct=runtime.settings.battery_low_pct,
        issued=issued.of([action]),
        deadline_s=runtime.settings.command_deadline_s,
    )
    return ActionResult(drone=stack.name, action=action, accepted=out.accepted, detail=out.detail)


@router.get(
    "/{drone_id}/video.mjpg",
    response_class=StreamingResponse,
    responses={200: {"content": {f"multipart/x-mixed-replace; boundary={MJPEG_BOUNDARY}": BINARY}}},
)
async def video(request: Request, stack: DroneDep, _role: RoleDep) -> StreamingResponse:
    """The front camera with the tracking overlay as an MJPEG stream (at most 15 fps)."""

    async def frames() -> AsyncIterator[bytes]:
        last = -1
        while not await request.is_disconnected():
            seq, jpeg = stack.latest_jpeg()
            if jpeg is not None and seq != last:
                last = seq
                yield (
                    (
                        f"--{MJPEG_BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                        f"Content-Length: {len(jpeg)}\r\n\r\n"
                    ).encode()
                    + jpeg
                    + b"\r\n"
                )
            await asyncio.sleep(1 / 15)

    return StreamingResponse(
        frames(), media_type=f"multipart/x-mixed-replace; boundary={MJPEG_BOUNDARY}"
    )
