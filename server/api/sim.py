"""Simulator only: ground truth and fault injection (``/sim/{id}/truth``, ``/sim/{id}/fault``)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException

from server.api.deps import DroneDep, LeaseDep, PilotDep, RoleDep
from server.api.models import FaultApplied, FaultRequest, SimTruth

router = APIRouter(prefix="/sim", tags=["simulator"])


@router.get("/{drone_id}/truth", response_model=SimTruth, response_model_exclude_unset=True)
def truth(stack: DroneDep, _role: RoleDep) -> dict[str, Any]:
    """The simulated drone's true pose, velocity, battery and control state."""
    if stack.sim is None:
        raise HTTPException(404, detail=f"{stack.name} is a real drone: no ground truth")
    return stack.truth()


@router.post("/{drone_id}/fault")
def fault(body: FaultRequest, stack: DroneDep, _role: PilotDep, _lease: LeaseDep) -> FaultApplied:
    """Inject a fault: link loss for a while, battery drained to a level, a wind gust, or clear.

    Needs the pilot lease to be free or held by the caller (409 otherwise)."""
    if stack.sim is None:
        raise HTTPException(status_code=404, detail=f"{stack.name} is a real drone: no faults")
    try:
        stack.inject_fault(body)
    except ValueError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from exc
    return FaultApplied(drone=stack.name, fault=body.kind, applied=True)
