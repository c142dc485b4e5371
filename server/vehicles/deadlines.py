"""Where a command's deadline is judged on the server side, and how an expired one is told.

The rule is :mod:`drone.deadline`'s; this module reads ``issued`` at the doors (the REST header
``X-Command-Issued`` or a body's ``issued``) and reports an expired command the same way from
every place that drops one: a warn line on ``/console/reply`` (spoken, like a refusal) and an
audit row with ``action`` ``expired`` and how late it was.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from drone.deadline import (
    BadIssued,
    Deadline,
    Expired,
    Verdict,
    audit_outcome,
    not_flown,
    parse_issued,
    stamp,
)
from server.msgs import header

log = logging.getLogger(__name__)

REPLY = "/console/reply"
REPLY_TYPE = "uav_console/Reply"
ISSUED_HEADER = "x-command-issued"


def issued_at_door(header_value: str | None, body_value: object, arrival: float) -> float:
    """When a REST command was issued: ``X-Command-Issued``, else the body's ``issued``, else
    its ``arrival`` (a script that says nothing); never later than its arrival.

    Raises:
        BadIssued: the value given is not Unix seconds, or is far ahead of our clock.
    """
    raw: object = header_value if header_value not in (None, "") else body_value
    return stamp(None if raw is None else parse_issued(raw), arrival)


def judge(deadline_s: float, kind: str | tuple[str, ...], issued: float | None) -> Verdict:
    """The verdict on a command issued at ``issued`` (None: now), handed over now."""
    rule = Deadline(deadline_s)
    now = time.time()
    kinds = (kind,) if isinstance(kind, str) else kind
    return rule.judge_all(kinds, now if issued is None else issued, now)


def reply_message(text: str, drone: str, prefix: str, *, utterance: str = "") -> dict[str, Any]:
    """A ``/console/reply`` warn line (in a fleet the drone's name leads it)."""
    return {
        "header": header(now=None),
        "text": f"{drone}: {text}" if prefix else text,
        "level": "warn",
        "speak": True,
        "utterance": utterance,
        "commands": "[]",
        "drone": drone,
        "alarm": "",
        "expects": "",
    }


class RestCommandExpired(Exception):
    """A REST command past its deadline at the door (REST: 409, ``accepted: false``)."""

    def __init__(self, text: str, verdict: Expired) -> None:
        super().__init__(text)
        self.text = text
        self.verdict = verdict


def say(graph: Any, text: str, drone: str, prefix: str, *, utterance: str = "") -> None:
    """Publish ``text`` as a ``/console/reply`` warn line (never raises: a reply that cannot be
    said must not stop the door or the audit row)."""
    try:
        msg = reply_message(text, drone, prefix, utterance=utterance)
        graph.publish(REPLY, msg, type=REPLY_TYPE)
    except Exception as exc:
        log.error("%s: expired command not said: %s", drone, exc)


def audit_row(
    audit: Any,
    text: str,
    verdict: Expired,
    *,
    kind: str,
    drone: str,
    source: str,
    role: str = "pilot",
    utterance: str = "",
) -> None:
    """The audit row of an expired command (``action`` ``expired``, the outcome saying how
    late), on the log's own writer thread where it has one. Never raises."""
    try:
        write = getattr(audit, "append_later", audit.append)
        write(
            utterance=utterance,
            commands=[{"action": kind}],
            action="expired",
            outcome=f"{audit_outcome(verdict)}. {text}",
            role=role,
            source=source,
            drone=drone,
        )
    except Exception as exc:
        log.error("%s: audit row of an expired command not written: %s", drone, exc)


def report_expired(
    graph: Any,
    audit: Any,
    what: str,
    verdict: Expired,
    *,
    kind: str,
    drone: str,
    prefix: str,
    source: str,
    role: str = "pilot",
    utterance: str = "",
) -> str:
    """Say (``graph``; None: not said) and audit (``audit``, an
    :class:`~server.store.AuditLog`, or None) an expired command; returns the line."""
    text = not_flown(what, verdict)
    log.warning("%s: %s", drone, text)
    if graph is not None:
        say(graph, text, drone, prefix, utterance=utterance)
    if audit is not None:
        audit_row(
            audit,
            text,
            verdict,
            kind=kind,
            drone=drone,
            source=source,
            role=role,
            utterance=utterance,
        )
    return text


__all__ = [
    "BadIssued",
    "RestCommandExpired",
    "audit_row",
    "issued_at_door",
    "judge",
    "reply_message",
    "report_expired",
    "say",
]
