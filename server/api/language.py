"""``POST /interpret`` (NLU only) and ``POST /command`` (through the dialog manager)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request

from drone.deadline import Expired
from server.api.deps import IssuedDep, PilotDep, RoleDep, RuntimeDep, check_lease
from server.api.models import CommandRequest, CommandResponse, InterpretRequest, InterpretResponse
from server.dialog.addressing import parse_address, recipients
from server.dialog.manager import DialogResult
from server.vehicles import deadlines
from server.vehicles.errors import VehicleUnavailable

router = APIRouter(tags=["language"])


@router.post("/interpret", response_model=InterpretResponse)
def interpret(body: InterpretRequest, runtime: RuntimeDep, _role: RoleDep) -> InterpretResponse:
    """What the NLU understands in ``text`` (in ``state``'s grammars if given); acts on nothing."""
    try:
        commands = runtime.interpret(body.text, body.state)
    except KeyError as exc:
        raise HTTPException(status_code=422, detail=f"unknown dialog state {exc}") from exc
    return InterpretResponse(text=body.text, commands=commands)


@router.post("/command", response_model=CommandResponse)
async def command(
    body: CommandRequest, request: Request, runtime: RuntimeDep, role: PilotDep, issued: IssuedDep
) -> CommandResponse:
    """Say ``text`` to a drone's dialog manager, as if spoken with ``confidence``.

    Needs the pilot lease to be free unless all it asks is land, emergency or hover (409).
    503 (``Retry-After``) when the one drone addressed has a flight process that is starting,
    gone or silent (``server.vehicles.remote``); a fleet command tells which drones missed it.
    ``issued`` (or ``X-Command-Issued``): when the operator gave it; a motion command handed to
    the drone past ``command_deadline_s`` is not flown (``accepted: false``, "Not flown: …").
    """
    address = parse_address(body.text)
    understood = runtime.interpret(address.text, None)
    check_lease(request, runtime, {c["action"] for c in understood})
    name = body.drone or runtime.default_drone
    if name not in runtime.dialogs:
        raise HTTPException(status_code=404, detail=f"no drone '{name}'")
    # "uav2 take off", "all drones land": the sentence names its drones.
    targets = recipients(address, name, list(runtime.dialogs))
    if not targets:
        named = ", ".join(address.names or ())
        raise HTTPException(
            status_code=404,
            detail=f"there is no drone {named} (drones here: {', '.join(runtime.dialogs)})",
        )
    # A stated confidence means recognised speech: below the threshold it is not executed.
    source = "speech" if "confidence" in body.model_fields_set else "rest"
    runtime.note_utterance(body.text, source=source, confidence=body.confidence, drone=name)
    kinds = tuple(str(c["action"]) for c in understood)
    when = issued.of(kinds)
    late = deadlines.judge(runtime.settings.command_deadline_s, kinds, when)
    if understood and isinstance(late, Expired):  # already late here: not passed on
        text = deadlines.report_expired(
            runtime.graph,
            runtime.audit,
            body.text,
            late,
            kind=kinds[0] if len(kinds) == 1 else "utterance",
            drone=name,
            prefix="" if len(runtime.dialogs) == 1 else f"/{name}",
            source=source,
            role=role,
            utterance=body.text,
        )
        return CommandResponse(reply=text, commands=understood, accepted=False, expects="")
    results = []
    for t in targets:
        try:
            result = await runtime.dialogs[t].handle_utterance(
                body.text, confidence=body.confidence, source=source, role=role, issued=when
            )
        except VehicleUnavailable as exc:
            if len(targets) == 1:
                raise  # 503 with Retry-After (server.app): nothing else was done
            # "all drones land": the others have their command; say who did not get it
            result = DialogResult(f"{exc}.", [], False)
        results.append(result)
    return CommandResponse(
        reply=" ".join(r.reply for r in results),
        commands=results[0].commands,
        accepted=all(r.accepted for r in results),
        expects=results[0].expects if len(results) == 1 else "",
    )
