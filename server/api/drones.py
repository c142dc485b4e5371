"""Drones: telemetry, direct actions (take off, land, hover, emergency, reset), describe, video."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import StreamingResponse

from server.api.deps import DroneDep, IssuedDep, PilotDep, RoleDep, RuntimeDep, check_lease
from server.api.models import ActionResult, Describe
from server.direct_actions import command_source, perform_async
from server.vehicles.safety import advertised_url

router = APIRouter(prefix="/drones", tags=["drones"])

Action = Literal["takeoff", "land", "hover", "emergency", "reset"]
MJPEG_BOUNDARY = "frame"


def _for_caller(out: dict[str, Any], request: Request) -> dict[str, Any]:
    """A vehicle process's ``safety_url`` as this caller can call it (the host it reached us
    by: a phone on the LAN gets the LAN address, not the vehicle's loopback or wildcard)."""
    vehicle = out.get("vehicle")
    if isinstance(vehicle, dict) and vehicle.get("safety_url"):
        vehicle["safety_url"] = advertised_url(vehicle["safety_url"], request.headers.get("host"))
    return out


@router.get("")
def list_drones(request: Request, runtime: RuntimeDep, _role: RoleDep) -> list[dict[str, Any]]:
    """Every drone with its telemetry, state, task and link."""
    return [_for_caller(stack.telemetry(), request) for stack in runtime.drones.values()]


@router.get("/{drone_id}")
def get_drone(request: Request, stack: DroneDep, _role: RoleDep) -> dict[str, Any]:
    """One drone: telemetry, pose estimate, control state, task, link and controller timing.

    ``vehicle.safety_url`` (a drone in its own process): its safety port, at the host this
    request named, for ``POST …/emergency`` and ``…/land`` that no web traffic can delay."""
    return _for_caller(stack.telemetry(), request)


@router.post("/{drone_id}/describe", response_model=Describe)
async def describe(stack: DroneDep, runtime: RuntimeDep, _role: RoleDep) -> Describe:
    """Caption the latest camera frame with the ONNX captioner (503 when it is unavailable)."""
    status = runtime.captioner_status()
    if status != "ready":
        raise HTTPException(status_code=503, detail=status)
    text, ms = await runtime.describe(stack.name)
    return Describe(drone=stack.name, text=text, ms=ms)


@router.post("/{drone_id}/{action}", response_model=ActionResult)
async def act(
    action: Action,
    request: Request,
    stack: DroneDep,
    runtime: RuntimeDep,
    _role: PilotDep,
    issued: IssuedDep,
) -> ActionResult:
    """Direct control; land and emergency reach the wire ahead of anything queued.

    Anything but land, emergency and hover needs the pilot lease to be free (409 otherwise).
    A take-off the drone cannot do now is not sent: ``accepted: false`` and ``detail`` says why
    and what to do. ``X-Command-Source`` (button, keyboard, map) is recorded in the audit log.
    ``X-Command-Issued`` (or a JSON body's ``issued``): Unix seconds when the operator gave
    it; a take-off or reset that reaches the drone more than ``command_deadline_s`` later is
    not sent (``accepted: false``, "Not flown: …"); a stop never expires, and a bad stamp
    (422 for the others) never holds it back.
    """
    check_lease(request, runtime, {action})
    out = await perform_async(
        stack,
        runtime.dialogs.get(stack.name),
        runtime.audit,
        action,
        source=command_source(request.headers.get("x-command-source")),
        battery_low_pct=runtime.settings.battery_low_pct,
        issued=issued.of([action]),
        deadline_s=runtime.settings.command_deadline_s,
    )
    return ActionResult(drone=stack.name, action=action, accepted=out.accepted, detail=out.detail)


@router.get("/{drone_id}/video.mjpg")
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
