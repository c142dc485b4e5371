"""What a vehicle's own parts say, on the central graph under the vehicle's own name, re-published
by the console after checking: the console is the only publisher of ``/console/reply``.

A vehicle runs no dialog (its console runs the drone's), but its nodes still say a few things
themselves: a command that reached the drone past its deadline (:mod:`server.vehicles.deadlines`),
a MAVLink autopilot's denials and failsafes (:mod:`server.nodes.mavros_node`).

Vehicle side (:func:`replies_out`, on the vehicle's own graph): what is said on
``/console/reply`` is copied to ``/NAME/vehicle/reply`` (:mod:`server.vehicles.names`), which
the bus carries.

Console side (:class:`ReplyRelay`, on the central graph): each reply is checked (it names this
vehicle's drone, or none, then it is filled in; a known level; text that is text) and published
on ``/console/reply``. A reply that fails the check is dropped with a log line: one vehicle
cannot speak as another drone, nor as the console.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from server.graph import Graph, Subscription
from server.vehicles import names

log = logging.getLogger("uav_console.vehicles")

REPLY = "/console/reply"
REPLY_TYPE = "uav_console/Reply"
# The levels a console speaks at (info, warn, alert; the page knows these).
LEVELS = frozenset({"info", "warn", "warning", "alert", "error"})
MAX_TEXT = 4000  # characters: far above any reply, far below a flood


class _Closer:
    def __init__(self, close: Callable[[], None]) -> None:
        self.close = close


def replies_out(graph: Graph, name: str) -> _Closer:
    """On a vehicle's graph: copy what its parts say to the vehicle's own reply topic;
    ``close()`` undoes it."""
    owner = f"relay:{name}"
    reply = names.reply_topic(name)
    graph.advertise(reply, REPLY_TYPE, owner=owner)
    sub = graph.subscribe(REPLY, lambda m: graph.publish(reply, m), type=REPLY_TYPE, owner=owner)

    def close() -> None:
        sub.close()
        graph.unadvertise(reply, owner)

    return _Closer(close)


def checked_reply(msg: dict[str, Any], drone: str) -> tuple[dict[str, Any] | None, str]:
    """``msg`` as the console re-publishes it for vehicle ``drone`` (its ``drone`` filled in),
    or None and why it is refused."""
    said = msg.get("drone") or ""
    if said not in ("", drone):
        return None, f"it names drone {said!r}"
    level = msg.get("level") or "info"
    if level not in LEVELS:
        return None, f"unknown level {level!r}"
    text = msg.get("text")
    if not isinstance(text, str) or len(text) > MAX_TEXT:
        return None, "its text is not a string of at most 4000 characters"
    return {**msg, "drone": drone, "level": level}, ""


class ReplyRelay:
    """The console side for one vehicle (see the module docstring); ``close()`` to stop."""

    def __init__(self, graph: Graph, name: str) -> None:
        self.graph = graph
        self.name = name
        self.relayed = 0
        self.refused: list[str] = []  # why, newest last (bounded)
        graph.advertise(REPLY, REPLY_TYPE)
        self._subs: list[Subscription] = [
            graph.subscribe(names.reply_topic(name), self._on_reply, type=REPLY_TYPE),
        ]

    def _on_reply(self, msg: dict[str, Any]) -> None:
        out, why = checked_reply(msg, self.name)
        if out is None:
            self.refused.append(f"reply: {why}")
            del self.refused[:-50]
            log.warning("%s: reply from its vehicle not re-published: %s", self.name, why)
            return
        self.relayed += 1
        self.graph.publish(REPLY, out)

    def close(self) -> None:
        for sub in self._subs:
            sub.close()
        self._subs = []


__all__ = ["ReplyRelay", "checked_reply", "replies_out"]
