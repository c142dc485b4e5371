"""Direct actions (buttons, keyboard shortcuts, REST): checked, sent, said and audited.

``POST /api/v1/drones/{id}/{action}`` comes here. A take-off the drone cannot do now (in
emergency, battery below the low threshold, no link) is refused before anything is sent, with
the reason and the way out (drone.preflight): the caller gets ``accepted: false`` and
the reason, the dialog says it aloud on ``/console/reply``. Every action, accepted or refused,
is written to the audit log with where it came from (a button, a keyboard shortcut, a script),
like a spoken command.

An action issued at ``issued`` (Unix seconds) and handed over past the deadline is not sent
(drone/deadline.py; stops never expire): ``accepted: false`` with "Not flown: …", said by the
dialog and audited as ``expired``.

A stop (land, hover, emergency) that carries an ``id`` comes down two roads from the page (this
one and the vehicle's safety door): :func:`perform_stop` runs each id once, whichever road
brings it first, and not at all once the operator superseded it (server.vehicles.stops).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from drone.deadline import (
    DEFAULT_DEADLINE_S,
    STOPS,
    Deadline,
    Expired,
    audit_outcome,
    label,
    not_flown,
)
from drone.preflight import DroneFacts, refusal
from server.vehicles.stops import StopVerdict

# Where a direct action came from: the page says which (X-Command-Source); anything else is
# recorded as "rest". Kept to a fixed set so the audit log holds no client-chosen text.
SOURCES = frozenset({"button", "keyboard", "map", "rest"})


@dataclass(frozen=True)
class DirectOutcome:
    accepted: bool
    detail: str
    expired: Expired | None = None  # not sent: it came past its deadline


def late(action: str, issued: float | None, deadline_s: float) -> DirectOutcome | None:
    """The outcome of ``action`` issued at ``issued`` if it is past its deadline now (None:
    in time, a stop, or no ``issued``)."""
    if issued is None:
        return None
    verdict = Deadline(deadline_s).judge(action, issued, time.time())
    if not isinstance(verdict, Expired):
        return None
    return DirectOutcome(False, not_flown(label(action), verdict), verdict)


def command_source(header: str | None) -> str:
    """The audit ``source`` for an ``X-Command-Source`` header value."""
    value = (header or "").strip().lower()
    return value if value in SOURCES else "rest"


def drone_facts(stack: Any) -> DroneFacts:
    """What the refusal check needs, from the vehicle in this process or, for a vehicle in
    its own process (``server.vehicles.remote``), from its latest telemetry."""
    snapshot = getattr(stack.vehicle, "snapshot", None)
    if callable(snapshot):
        snap = snapshot()
        return DroneFacts(
            bool(snap.emergency),
            float(snap.battery_pct),
            bool(snap.link_ok),
            bool(snap.flying),
            bool(getattr(snap, "battery_known", True)),
            str(getattr(snap, "navdata_doubt", "")),
        )
    t = stack.telemetry()
    return DroneFacts(
        bool(t.get("emergency", False)),
        float(t.get("battery_pct", 0.0)),
        bool(t.get("link_ok", False)),
        bool(t.get("flying", False)),
        bool(t.get("battery_known", True)),
        str(t.get("navdata_doubt", "")),
    )


async def perform_async(
    stack: Any,
    dialog: Any,
    audit: Any,
    action: str,
    *,
    source: str,
    battery_low_pct: float,
    issued: float | None = None,
    deadline_s: float = DEFAULT_DEADLINE_S,
) -> DirectOutcome:
    """:func:`perform` for any drone: a drone in its own vehicle process
    (``server.vehicles.remote``, which has ``act``) checks and does the action there, on its
    state now; its dialog (here) follows and says a refusal; the audit row is written here.
    A motion action is judged against its deadline here, as the console hands it over, and
    by the vehicle again as it receives it (``act_in_time``).

    Raises:
        VehicleUnavailable: that vehicle is not on the link (a stop is still sent).
    """
    act = getattr(stack, "act", None)
    if act is None:
        return perform(
            stack,
            dialog,
            audit,
            action,
            source=source,
            battery_low_pct=battery_low_pct,
            issued=issued,
            deadline_s=deadline_s,
        )
    in_time = getattr(stack, "act_in_time", None)
    if action not in STOPS and in_time is not None:
        outcome = late(action, issued, deadline_s)
        if outcome is not None:
            if dialog is not None:
                dialog.announce(outcome.detail, "warn")
        else:
            try:
                outcome = await in_time(action, battery_low_pct, issued)
            except Exception as exc:
                _audit(audit, stack, dialog, action, source, DirectOutcome(False, str(exc)))
                raise
            _tell(dialog, action, outcome)
        _audit(audit, stack, dialog, action, source, outcome)
        return outcome
    try:
        accepted, detail = await act(action, battery_low_pct)
    except Exception as exc:
        _audit(audit, stack, dialog, action, source, DirectOutcome(False, str(exc)))
        raise
    outcome = DirectOutcome(accepted, detail)
    _tell(dialog, action, outcome)
    _audit(audit, stack, dialog, action, source, outcome)
    return outcome


def _tell(dialog: Any, action: str, outcome: DirectOutcome) -> None:
    """The drone's dialog follows an action a vehicle process did, or says its refusal."""
    if dialog is None:
        return
    if outcome.accepted:
        dialog.note_direct(action)
    else:
        dialog.announce(outcome.detail, "warn")


def perform_stop(
    stack: Any,
    dialog: Any,
    audit: Any,
    action: str,
    stop_id: str,
    issued: float | None,
    road: str,
    *,
    source: str,
    battery_low_pct: float,
    now: float,
) -> StopVerdict:
    """A stop with an id, where the drone is driven (the web process inline, or a vehicle
    process): run at once on its first arrival (:func:`perform`), answered with that first
    delivery when it comes again by the other road, dropped when superseded.

    Args:
        road: ``server`` (REST, the console's ``direct`` call) or ``door``.
        now: unix seconds, the clock ``issued`` is on.
    """
    verdict: StopVerdict = stack.stops.admit(stop_id, action, issued, road, now)
    if verdict.run:
        perform(stack, dialog, audit, action, source=source, battery_low_pct=battery_low_pct)
    elif not verdict.accepted:
        _audit(audit, stack, dialog, action, source, DirectOutcome(False, verdict.detail))
    return verdict


async def perform_stop_async(
    stack: Any,
    dialog: Any,
    audit: Any,
    action: str,
    stop_id: str,
    issued: float | None,
    *,
    source: str,
    battery_low_pct: float,
) -> StopVerdict:
    """:func:`perform_stop` down the server road for any drone: a drone in its own vehicle
    process (``act_stop``) gets the stop with its id and decides there (its door may have
    brought it first); the audit row is written here.

    Raises:
        VehicleUnavailable: that vehicle is not on the link (the stop is still sent).
    """
    act_stop = getattr(stack, "act_stop", None)
    if act_stop is None:
        return perform_stop(
            stack,
            dialog,
            audit,
            action,
            stop_id,
            issued,
            "server",
            source=source,
            battery_low_pct=battery_low_pct,
            now=time.time(),
        )
    try:
        verdict: StopVerdict = await act_stop(action, stop_id, issued)
    except Exception as exc:
        _audit(audit, stack, dialog, action, source, DirectOutcome(False, str(exc)))
        raise
    if verdict.accepted and dialog is not None:
        dialog.note_direct(action)
    _audit(audit, stack, dialog, action, source, DirectOutcome(verdict.accepted, verdict.detail))
    return verdict


def perform(
    stack: Any,
    dialog: Any,
    audit: Any,
    action: str,
    *,
    source: str,
    battery_low_pct: float,
    issued: float | None = None,
    deadline_s: float = DEFAULT_DEADLINE_S,
) -> DirectOutcome:
    """Check ``action`` against the drone's state, send it if it may run, tell and audit.
    An action past its deadline (``issued``, ``deadline_s``; stops never) is not sent.

    Runs on the event loop (the dialog manager's thread): the command reaches the driver
    first, then the dialog is told; the audit row is written on the log's writer thread, so
    its fsync never delays the datagram (bench/direct_actions.py measures this).

    Args:
        stack: the drone (``server.vehicles.stack.DroneStack``).
        dialog: its dialog manager (or None), told so its state follows and refusals are said.
        audit: the audit log (``server.store.AuditLog``) or None.
    """
    expired = late(action, issued, deadline_s)
    why = None if expired is not None else refusal(action, drone_facts(stack), battery_low_pct)
    if expired is not None:
        outcome = expired
        if dialog is not None:
            dialog.announce(expired.detail, "warn")
    elif why is None:
        detail = stack.direct(action)
        outcome = DirectOutcome(True, detail)
        if dialog is not None:
            dialog.note_direct(action)
    else:
        outcome = DirectOutcome(False, why)
        if dialog is not None:
            dialog.announce(why, "warn")
    _audit(audit, stack, dialog, action, source, outcome)
    return outcome


def _audit(
    audit: Any, stack: Any, dialog: Any, action: str, source: str, outcome: DirectOutcome
) -> None:
    if audit is not None:
        # On its own thread: the fsync must not hold the loop the driver sends from.
        verdict = outcome.expired
        audit.append_later(
            utterance="",
            commands=[{"action": action}],
            action="executed" if outcome.accepted else "expired" if verdict else "refused",
            outcome=f"{audit_outcome(verdict)}. {outcome.detail}" if verdict else outcome.detail,
            role="pilot",
            source=source,
            drone=stack.name,
            state=str(getattr(getattr(dialog, "state", None), "value", "")),
        )
