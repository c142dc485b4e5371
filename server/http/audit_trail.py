"""Intent before, outcome after: audit rows for every action that moves a drone or changes who
controls it, whatever its door.

Rows go to the same SQLite audit log as the dialog's (``server.store``), with ``source`` saying
which door (``rest``, ``rosbridge``, ``lease``), ``action`` ``intent:<what>`` or
``outcome:<what>``, and the outcome row naming its intent's id. An intent row is committed before
the action is taken, except for ``land`` and ``emergency``: they reach the wire first (DESIGN §5:
nothing may delay them, not even an fsync) and both rows follow at once, the intent stamped with
the time the request arrived.

:class:`RestAuditMiddleware` does this for the REST door: a pilot's ``POST`` to a drone action,
a mission, a simulator fault, or a take-over; unauthenticated or refused-at-the-door requests
write nothing (a flood of them must not fill the disk). Writes run in a worker thread so the
loop never waits on an fsync.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections.abc import Awaitable, Callable, MutableMapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs

from server.http.security import Role, Security, token_from
from server.store import AuditError, AuditLog

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


SAFETY = frozenset({"land", "emergency"})

# (method, path pattern) -> what the request does; group "drone" names the drone if any.
_AUDITED: tuple[tuple[str, re.Pattern[str], str], ...] = (
    (
        "POST",
        re.compile(
            r"^/api/v1/drones/(?P<drone>[^/]+)/(?P<what>takeoff|land|hover|emergency|reset)$"
        ),
        "",
    ),
    ("POST", re.compile(r"^/api/v1/missions$"), "mission_start"),
    ("DELETE", re.compile(r"^/api/v1/missions/(?P<mission>[^/]+)$"), "mission_stop"),
    ("POST", re.compile(r"^/api/v1/sim/(?P<drone>[^/]+)/fault$"), "sim_fault"),
)


@dataclass
class AuditTrail:
    """Writes intent and outcome rows to ``log``."""

    log: AuditLog

    def intent(
        self,
        what: str,
        *,
        role: str,
        source: str,
        drone: str,
        detail: str,
        now: float | None = None,
    ) -> int:
        """The intent row (committed on return); its id, for :meth:`outcome`."""
        return self.log.append(
            utterance=detail,
            commands=[{"action": what}],
            action=f"intent:{what}",
            outcome="pending",
            role=role,
            source=source,
            drone=drone,
            now=now,
        )

    def outcome(
        self, intent_id: int, what: str, result: str, *, role: str, source: str, drone: str
    ) -> int:
        """The outcome row of intent ``intent_id``."""
        return self.log.append(
            utterance=f"intent #{intent_id}",
            commands=[{"action": what}],
            action=f"outcome:{what}",
            outcome=result,
            role=role,
            source=source,
            drone=drone,
        )

    def both(
        self, what: str, result: str, *, role: str, source: str, drone: str, detail: str, at: float
    ) -> None:
        """Intent (stamped ``at``) and outcome together: for land and emergency, which act first."""
        iid = self.intent(what, role=role, source=source, drone=drone, detail=detail, now=at)
        self.outcome(iid, what, result, role=role, source=source, drone=drone)

    def lease_changed(self, previous: str | None, holder: str | None, how: str) -> None:
        """A change of who holds the pilot lease (one row: the change has already happened,
        it is made by the lease itself, atomically). Written on the log's writer thread
        (:meth:`~server.store.AuditLog.append_later`): off the loop (the row is fsynced) and in
        order with the REST rows around it (a take-over's intent, then the change, then its
        outcome); a failed write is logged, never raised to the lease."""
        self.log.append_later(
            utterance=f"{previous or 'nobody'} -> {holder or 'nobody'}",
            commands=[{"action": "lease", "how": how}],
            action=f"lease:{how}",
            outcome="done",
            role="pilot",
            source="lease",
            drone="*",
        )


def audited(method: str, path: str) -> tuple[str, str] | None:
    """(what, drone) if a ``method path`` request is audited, else None."""
    for m, pattern, what in _AUDITED:
        if m != method:
            continue
        match = pattern.match(path)
        if match is not None:
            groups = match.groupdict()
            return what or groups.get("what", "?"), groups.get("drone") or "*"
    return None


@dataclass
class RestAuditMiddleware:
    """ASGI middleware: intent and outcome rows for a pilot's REST actions (module docstring)."""

    app: ASGIApp
    security: Security
    trail: AuditTrail

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        method, path = scope.get("method", ""), scope.get("path", "")
        hit = audited(method, path)
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        take_over = (query.get("take_over") or [""])[0].lower() in ("1", "true", "yes")
        if hit is None and not take_over:
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        cookies = _cookies(headers.get("cookie", ""))
        flat = {k: v[0] for k, v in query.items()}
        role = self.security.role_for(token_from(headers, flat, cookies))
        if role is not Role.PILOT:
            await self.app(scope, receive, send)  # refused at the door: nothing happened
            return
        what, drone = hit if hit is not None else ("take_over", "*")
        detail = f"{method} {path}" + ("?take_over=true" if take_over else "")
        status: list[int] = []

        async def send_status(message: Message) -> None:
            if message["type"] == "http.response.start":
                status.append(int(message["status"]))
            await send(message)

        arrived = time.time()
        if what in SAFETY:
            try:
                await self.app(scope, receive, send_status)
            finally:
                result = f"HTTP {status[0]}" if status else "no response"
                await _in_order(
                    self.trail.log,
                    self.trail.both,
                    what,
                    result,
                    role="pilot",
                    source="rest",
                    drone=drone,
                    detail=detail,
                    at=arrived,
                )
            return
        iid = await _in_order(
            self.trail.log,
            self.trail.intent,
            what,
            role="pilot",
            source="rest",
            drone=drone,
            detail=detail,
        )
        try:
            await self.app(scope, receive, send_status)
        finally:
            result = f"HTTP {status[0]}" if status else "no response"
            await _in_order(
                self.trail.log,
                self.trail.outcome,
                iid,
                what,
                result,
                role="pilot",
                source="rest",
                drone=drone,
            )


async def _in_order(log: AuditLog, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
    """``fn(*args, **kw)`` (a write to ``log``) on the log's writer thread, so that its rows
    keep their order with the rows written there meanwhile (a lease change's)."""
    try:
        return await asyncio.wrap_future(log.in_order(lambda: fn(*args, **kw)))
    except AuditError:
        return -1  # the log's own error already names the file; acting is not blocked by it


def _cookies(header: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for part in header.split(";"):
        name, sep, value = part.strip().partition("=")
        if sep:
            out[name] = value
    return out
