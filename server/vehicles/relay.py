"""A vehicle's dialog on the central graph, under the vehicle's own name, re-published by the
console after checking: the console is the only publisher of ``/console/reply``.

Vehicle side (:func:`dialog_out`, on the vehicle's own graph): its dialog manager speaks on
``/console/reply`` and ``PREFIX/console/state`` and answers ``PREFIX/console/interpret``, as an
in-process one does; these are copied to ``/NAME/vehicle/reply``, ``/NAME/vehicle/state`` and
``/NAME/vehicle/interpret`` (:mod:`server.vehicles.names`), which the link carries.

Console side (:class:`DialogRelay`, on the central graph): each reply is checked (it names this
vehicle's drone, or none, then it is filled in; a known level; text that is text) and published
on ``/console/reply``; the state on ``PREFIX/console/state``; ``PREFIX/console/interpret`` calls the
vehicle's. A reply that fails the check is dropped with a log line: one vehicle cannot speak as
another drone, nor as the console.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from server.graph import INTERNAL, Graph, Subscription
from server.vehicles import names

log = logging.getLogger("uav_console.vehicle_link")

REPLY = "/console/reply"
STATE = "/console/state"
INTERPRET = "/console/interpret"
REPLY_TYPE = "uav_console/Reply"
STATE_TYPE = "uav_console/DialogState"
INTERPRET_TYPE = "uav_console/Interpret"
# The levels a dialog speaks at (server.dialog: info, warn, alert; the page knows these).
LEVELS = frozenset({"info", "warn", "warning", "alert", "error"})
MAX_TEXT = 4000  # characters: far above any reply, far below a flood


class _Closer:
    def __init__(self, close: Callable[[], None]) -> None:
        self.close = close


def dialog_out(graph: Graph, name: str, prefix: str) -> _Closer:
    """On a vehicle's graph: copy its dialog's reply, state and interpret service to the
    vehicle's own names; ``close()`` undoes it."""
    owner = f"relay:{name}"
    reply, state = names.reply_topic(name), names.state_topic(name)
    graph.advertise(reply, REPLY_TYPE, owner=owner)
    graph.advertise(state, STATE_TYPE, latch=True, owner=owner)
    subs = [
        graph.subscribe(REPLY, lambda m: graph.publish(reply, m), type=REPLY_TYPE, owner=owner),
        graph.subscribe(
            f"{prefix}{STATE}", lambda m: graph.publish(state, m), type=STATE_TYPE, owner=owner
        ),
    ]
    local_interpret = f"{prefix}{INTERPRET}"

    async def interpret(args: dict[str, Any]) -> dict[str, Any]:
        return await graph.call_service(local_interpret, args)

    graph.advertise_service(names.interpret_service(name), INTERPRET_TYPE, interpret, owner=owner)

    def close() -> None:
        for sub in subs:
            sub.close()
        graph.unadvertise_service(names.interpret_service(name), owner)
        graph.unadvertise(reply, owner)
        graph.unadvertise(state, owner)

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


class DialogRelay:
    """The console side for one vehicle (see the module docstring); ``close()`` to stop."""

    def __init__(self, graph: Graph, name: str, prefix: str) -> None:
        self.graph = graph
        self.name = name
        self.prefix = prefix
        self.relayed = 0
        self.refused: list[str] = []  # why, newest last (bounded)
        self.state_topic = f"{prefix}{STATE}"
        self.interpret_service = f"{prefix}{INTERPRET}"
        graph.advertise(REPLY, REPLY_TYPE)
        graph.advertise(self.state_topic, STATE_TYPE, latch=True)
        self._subs: list[Subscription] = [
            graph.subscribe(names.reply_topic(name), self._on_reply, type=REPLY_TYPE),
            graph.subscribe(names.state_topic(name), self._on_state, type=STATE_TYPE),
        ]
        # Owned by the server (graph.INTERNAL): no client may replace it.
        graph.advertise_service(self.interpret_service, INTERPRET_TYPE, self._interpret)

    def _refuse(self, what: str, why: str) -> None:
        self.refused.append(f"{what}: {why}")
        del self.refused[:-50]
        log.warning("%s: %s from its vehicle not re-published: %s", self.name, what, why)

    def _on_reply(self, msg: dict[str, Any]) -> None:
        out, why = checked_reply(msg, self.name)
        if out is None:
            self._refuse("reply", why)
            return
        self.relayed += 1
        self.graph.publish(REPLY, out)

    def _on_state(self, msg: dict[str, Any]) -> None:
        said = msg.get("drone") or ""
        if said not in ("", self.name):
            self._refuse("dialog state", f"it names drone {said!r}")
            return
        self.graph.publish(self.state_topic, {**msg, "drone": self.name})

    async def _interpret(self, args: dict[str, Any]) -> dict[str, Any]:
        return await self.graph.call_service(names.interpret_service(self.name), args)

    def close(self) -> None:
        for sub in self._subs:
            sub.close()
        self._subs = []
        self.graph.unadvertise_service(self.interpret_service, INTERNAL)


__all__ = ["DialogRelay", "checked_reply", "dialog_out"]
