"""FastAPI dependencies shared by the REST routers: the runtime and the caller's role."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Request

from drone.deadline import Expired, expires, label
from server.http.security import SAFETY_ACTIONS, TOKEN_COOKIE
from server.runtime import Runtime
from server.vehicles import deadlines
from server.vehicles.stack import DroneStack

REST_HOLDER = "rest"  # the lease holder id of REST callers after a take-over


def get_runtime(request: Request) -> Runtime:
    return request.app.state.runtime  # type: ignore[no-any-return]


def _token_from(request: Request) -> str | None:
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return request.query_params.get("token") or request.cookies.get(TOKEN_COOKIE)


def caller_role(request: Request, runtime: Annotated[Runtime, Depends(get_runtime)]) -> str:
    """The caller's role from a bearer token (or ``?token=``); 401 without a valid one."""
    role = runtime.security.role_for(_token_from(request))
    if role is None:
        raise HTTPException(
            status_code=401,
            detail="a valid token is required (Authorization: Bearer <token>)",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return str(role)


def pilot_role(role: Annotated[str, Depends(caller_role)]) -> str:
    """Only a pilot may command; observers get 403 naming their role."""
    if role != "pilot":
        raise HTTPException(status_code=403, detail=f"role '{role}' may not command the drones")
    return role


def check_lease(request: Request, runtime: Runtime, actions: set[str]) -> None:
    """A pilot on REST commands only while no other pilot holds the lease (DESIGN §5).

    Safety actions (land, emergency, hover) always get through. The holder itself (the console
    page, whose rosbridge session holds the lease) names the holding's secret key (told only to
    it by ``/console/lease``) in ``X-Pilot-Lease``. ``?take_over=true`` takes the lease from its
    holder, who is told; REST then keeps it (the other pilot must take it back explicitly).

    Raises:
        HTTPException: 409 naming the holder and how to take over.
    """
    if actions and actions <= SAFETY_ACTIONS:
        return
    lease = runtime.security.lease
    holder = lease.state.holder
    if holder is None or holder == REST_HOLDER:
        return
    if lease.key_matches(request.headers.get("x-pilot-lease")):
        return
    if request.query_params.get("take_over", "").lower() in ("1", "true", "yes"):
        lease.acquire(REST_HOLDER, time.time(), take_over=True)
        return
    raise HTTPException(
        status_code=409,
        detail="another pilot holds the pilot lease; repeat with ?take_over=true to take it over",
    )


def role_by_method(request: Request, runtime: Annotated[Runtime, Depends(get_runtime)]) -> str:
    """Reading needs any role; changing anything (POST, PUT, PATCH, DELETE) needs a pilot."""
    role = caller_role(request, runtime)
    if request.method not in ("GET", "HEAD", "OPTIONS"):
        return pilot_role(role)
    return role


def fleet_access(request: Request, runtime: Annotated[Runtime, Depends(get_runtime)]) -> str:
    """The fleet router's guard: reading needs any role; starting a mission needs a pilot and
    the lease (409 otherwise); stopping one needs a pilot only (any pilot may stop)."""
    role = role_by_method(request, runtime)
    if request.method == "POST":
        check_lease(request, runtime, {"mission"})
    return role


def lease_dep(request: Request, runtime: Annotated[Runtime, Depends(get_runtime)]) -> None:
    """A dependency for commands that are not safety actions: the lease must be free or ours."""
    check_lease(request, runtime, {"command"})


@dataclass(frozen=True)
class Issued:
    """When a REST command was issued (Unix seconds, server clock), or why the stamp it gave
    is not one (then ``at`` is its arrival)."""

    at: float
    error: str | None = None

    def of(self, kinds: tuple[str, ...] | list[str] | set[str]) -> float:
        """The time to judge commands of ``kinds`` by. A bad stamp refuses a motion command
        (422) but never holds a stop back: a stop is judged from its arrival (it never
        expires anyway).

        Raises:
            HTTPException: 422, the stamp is bad and a command of ``kinds`` can expire.
        """
        if self.error is not None and any(expires(k) for k in kinds):
            raise HTTPException(status_code=422, detail=self.error)
        return self.at


async def command_issued(request: Request) -> Issued:
    """When a REST command was issued (drone/deadline.py): the ``X-Command-Issued`` header,
    else the JSON body's ``issued``, else its arrival (a script that says nothing); never
    later than its arrival."""
    arrival = time.time()
    given = request.headers.get(deadlines.ISSUED_HEADER)
    body_value: object = None
    if not given and "json" in request.headers.get("content-type", ""):
        try:
            body = json.loads(await request.body() or b"null")
        except ValueError:
            body = None  # the route's own parsing says what is wrong with it
        if isinstance(body, dict):
            body_value = body.get("issued")
    try:
        return Issued(deadlines.issued_at_door(given, body_value, arrival))
    except deadlines.BadIssued as exc:
        return Issued(arrival, str(exc))


async def fleet_deadline(
    request: Request, runtime: Annotated[Runtime, Depends(get_runtime)]
) -> None:
    """Starting a mission or the patrol is a motion command: past its deadline at the door it
    is not started, but said, audited and answered (409, ``accepted: false``). Stopping one
    (DELETE) never expires."""
    if request.method != "POST":
        return
    kind = "patrol_start" if request.url.path.endswith("/patrol") else "mission"
    issued = (await command_issued(request)).of([kind])
    verdict = deadlines.judge(runtime.settings.command_deadline_s, kind, issued)
    if isinstance(verdict, Expired):
        text = deadlines.report_expired(
            runtime.graph,
            runtime.audit,
            label(kind),
            verdict,
            kind=kind,
            drone="*",
            prefix="",
            source="rest",
            utterance=f"POST {request.url.path}",
        )
        raise deadlines.RestCommandExpired(text, verdict)


def drone_stack(drone_id: str, runtime: Annotated[Runtime, Depends(get_runtime)]) -> DroneStack:
    stack = runtime.drones.get(drone_id)
    if stack is None:
        known = ", ".join(runtime.drones) or "none"
        raise HTTPException(status_code=404, detail=f"no drone '{drone_id}' (known: {known})")
    return stack


RuntimeDep = Annotated[Runtime, Depends(get_runtime)]
RoleDep = Annotated[str, Depends(caller_role)]
PilotDep = Annotated[str, Depends(pilot_role)]
DroneDep = Annotated[DroneStack, Depends(drone_stack)]
LeaseDep = Annotated[None, Depends(lease_dep)]
IssuedDep = Annotated[Issued, Depends(command_issued)]
