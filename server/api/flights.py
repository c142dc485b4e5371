"""Flight recordings: list, download (MCAP), delete (pilot only). See server/recorder."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse

from server.api.deps import RoleDep, RuntimeDep
from server.api.models import BINARY, FlightDeleted, FlightList
from server.recorder.errors import FlightNotFound, RecorderError

router = APIRouter(prefix="/flights", tags=["flights"])


@router.get("", response_model=FlightList, response_model_exclude_unset=True)
def list_flights(runtime: RuntimeDep, _role: RoleDep) -> dict[str, Any]:
    """Every recorded flight, oldest first: ``{"flights": [{id, started, ended, drones,
    bytes, messages}]}``; the flight being recorded has ``ended: null``."""
    return {"flights": [f.as_json() for f in runtime.flights()]}


@router.get(
    "/{flight_id}",
    response_class=FileResponse,
    responses={200: {"content": {"application/octet-stream": BINARY}}},
)
def download_flight(flight_id: str, runtime: RuntimeDep, _role: RoleDep) -> FileResponse:
    """The flight's MCAP file (open it in Foxglove, or ``uav-console replay FILE``).

    404 for an unknown id; 409 while it is still being recorded.
    """
    try:
        path = runtime.flight_index.path_for(flight_id)
    except FlightNotFound as exc:
        raise HTTPException(status_code=404, detail=str(exc)) from exc
    if flight_id == runtime.recording_id():
        raise HTTPException(
            status_code=409,
            detail=f"flight '{flight_id}' is being recorded; download it after the session "
            "ends (all drones landed and no command for a while)",
        )
    return FileResponse(
        path, media_type="application/octet-stream", filename=f"uav-console-{flight_id}.mcap"
    )


@router.delete("/{flight_id}")
def delete_flight(flight_id: str, runtime: RuntimeDep, role: RoleDep) -> FlightDeleted:
    """Delete a recording (pilot only: 403 for an observer; 404 unknown; 409 in progress)."""
    if role != "pilot":
        raise HTTPException(status_code=403, detail=f"role '{role}' may not delete recordings")
    try:
        runtime.flight_index.delete(flight_id, runtime.recording_id())
    except FlightNotFound as exc:
        raise HTTPException(status_code=404, detail=str(exc)) from exc
    except RecorderError as exc:
        raise HTTPException(status_code=409, detail=str(exc)) from exc
    return FlightDeleted(deleted=flight_id)
