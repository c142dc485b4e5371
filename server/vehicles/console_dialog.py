"""The dialog of a drone whose vehicle runs in its own process, run by the console.

The vehicle process runs no NLU and no dialog. Its console understands what the operator types,
says or sends by REST, checks it against the drone's state (its telemetry, at most 0.1 s old)
and hands the vehicle's task executor typed commands (drone/commands.py) over the bus, where
the vehicle's own executor decides again (:mod:`server.vehicles.task_ops`):

- :class:`RemoteTaskPort`: the dialog's :class:`~server.dialog.ports.TaskPort` as the control ops
  ``submit`` (awaited: the executor's decisions are the answer), ``preempt`` and ``cancel``, sent
  in the order the dialog gave them (a stop never waits for what went before it), and the
  executor's notices from ``/NAME/vehicle/task_event``. ``submit`` and ``preempt`` carry when
  the operator gave the sentence (``issued``, the console's Unix seconds): the vehicle judges
  the deadline again as it receives them (drone/deadline.py) and answers ``expired`` rather
  than fly a sentence late, which the dialog says as "Not flown" (audited ``expired``);
- :class:`RemoteVehicleView`: the dialog's :class:`~server.dialog.ports.VehiclePort` from the
  vehicle's telemetry;
- :class:`RemoteDialog`: a :class:`~server.dialog.manager.DialogManager` over those two that
  also says the vehicle supervisor's alarms (``/NAME/vehicle/alarm``), and answers REST with
  503 (:class:`~server.vehicles.errors.VehicleUnavailable`) while the vehicle has not joined
  or is silent, sending nothing.
"""

from __future__ import annotations

import asyncio
import contextvars
import json
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from drone.deadline import Expired, not_flown
from drone.supervisor.alarms import Alarm, BadAlarm
from server.dialog.adapters import task_events
from server.dialog.manager import DialogManager, DialogResult
from server.dialog.ports import DescribePort, DroneView, FleetPort, TaskDecision, TaskReport
from server.graph import Graph, GraphError
from server.language.nlu import NLU
from server.vehicles import names, remote
from server.vehicles.errors import CommandExpired, RemoteCallError, VehicleUnavailable
from server.vehicles.remote import RemoteDroneStack

log = logging.getLogger("uav_console.vehicle")

STOPS = frozenset({"land", "hover", "emergency"})
# When the operator gave the sentence the dialog is handling (Unix seconds, None: no deadline),
# set by :meth:`RemoteDialog._handle` for the task ops that sentence sends.
ISSUED: contextvars.ContextVar[float | None] = contextvars.ContextVar("issued", default=None)


class RemoteTaskPort:
    """See the module docstring; ``graph`` is the console's."""

    def __init__(self, stack: RemoteDroneStack, graph: Graph) -> None:
        self.stack = stack
        self._listeners: list[Callable[[TaskReport], None]] = []
        self._tail: asyncio.Future[Any] | None = None  # the last op sent, for the order
        self._pending: set[asyncio.Future[Any]] = set()
        self.on_failure: Callable[[str], None] = lambda text: None  # set by the dialog
        self._sub = graph.subscribe(
            names.task_event_topic(stack.name), self._on_notice, type=names.STRING
        )

    # ------------------------------------------------------------------ ops, in order
    def _then(self, args: dict[str, Any], *, stop: bool = False) -> asyncio.Future[Any]:
        """Send ``args`` after the op sent before it (a stop at once), with when the sentence
        was issued if it was said; its answer."""
        before = None if stop else self._tail
        issued = ISSUED.get()
        if issued is not None:
            args = {**args, "issued": issued}

        async def send() -> Any:
            if before is not None:
                await asyncio.wait({before})
            return await self.stack.call(
                args, join_wait_s=remote.COMMAND_JOIN_WAIT_S, silent_s=remote.SILENT_S
            )

        fut = asyncio.ensure_future(send())
        self._tail = fut
        self._pending.add(fut)
        fut.add_done_callback(self._pending.discard)
        return fut

    async def submit(self, commands: Sequence[Mapping[str, Any]]) -> list[TaskDecision]:
        """Queue a sentence's commands on the vehicle; its executor's decisions.

        Raises:
            VehicleUnavailable: the vehicle is not there or fell silent (REST: 503).
            CommandExpired: the vehicle received them past their deadline and ran none.
        """
        sent = [dict(c) for c in commands]
        try:
            out = await self._then({"op": "submit", "commands": sent})
        except VehicleUnavailable:
            raise
        except (GraphError, RemoteCallError) as exc:
            why = f"{self.stack.name} cannot be reached now ({exc})"
            return [TaskDecision(False, why) for _ in commands]
        late = expiry(out)
        if late is not None:
            raise CommandExpired(
                str(out.get("detail", "")),
                age_s=late.age_s,
                deadline_s=late.deadline_s,
                commands=sent,
            )
        decisions = out.get("decisions") if isinstance(out, dict) else None
        if not isinstance(decisions, list) or len(decisions) != len(commands):
            why = str(out.get("detail", "")) if isinstance(out, dict) else ""
            why = why or f"{self.stack.name} gave no decision"
            return [TaskDecision(False, why) for _ in commands]
        return [
            TaskDecision(bool(d.get("accepted")), str(d.get("reason", "")), bool(d.get("question")))
            for d in decisions
            if isinstance(d, dict)
        ]

    def cancel(self) -> None:
        self._fire({"op": "cancel"}, "cancel")

    def preempt(self, command: Mapping[str, Any], by: str = "") -> None:
        action = str(command.get("action", ""))
        stop = action in STOPS and len(command) == 1
        self._fire({"op": "preempt", "command": dict(command), "by": by}, action, stop=stop)

    def _fire(self, args: dict[str, Any], what: str, *, stop: bool = False) -> None:
        fut = self._then(args, stop=stop)

        def done(f: asyncio.Future[Any]) -> None:
            if f.cancelled():
                return
            exc = f.exception()
            out = None if exc is not None else f.result()
            refused = isinstance(out, dict) and out.get("accepted") is False
            if exc is None and not refused:
                return
            why = str(exc) if exc is not None else str(out.get("detail", ""))  # type: ignore[union-attr]
            log.warning("%s: %s not done: %s", self.stack.name, what, why)
            late = expiry(out) is not None
            self.on_failure(why if late else f"{what} did not reach {self.stack.name}: {why}")

        fut.add_done_callback(done)

    # ------------------------------------------------------------------ notices
    def on_event(self, callback: Callable[[TaskReport], None]) -> None:
        self._listeners.append(callback)

    def _on_notice(self, msg: dict[str, Any]) -> None:
        try:
            notice = json.loads(str(msg.get("data", "")))
        except ValueError:
            log.warning("%s: a task notice that is not JSON", self.stack.name)
            return
        if not isinstance(notice, dict):
            return
        idle = notice.get("state") == "idle" and not notice.get("queued")
        for event in task_events(
            str(notice.get("kind", "")), str(notice.get("task", "")), str(notice.get("text", ""))
        ):
            for cb in self._listeners:
                cb(event)
            if event.kind in ("done", "failed", "took_off") and idle:
                for cb in self._listeners:
                    cb(TaskReport("idle"))

    def close(self) -> None:
        self._sub.close()


class RemoteVehicleView:
    """The drone as its telemetry says (≤ 0.1 s old), for the dialog's checks."""

    def __init__(self, stack: RemoteDroneStack, world: Any) -> None:
        self.stack = stack
        self._markers = frozenset(int(m.id) for m in getattr(world, "markers", ()))

    def snapshot(self) -> DroneView:
        t = self.stack.last
        markers = []
        for m in t.get("markers") or ():
            if isinstance(m, dict) and isinstance(m.get("id"), int):
                markers.append(int(m["id"]))
        return DroneView(
            battery_pct=_num(t.get("battery_pct"), 0.0),
            altitude_m=_num(t.get("altitude_m"), 0.0),
            flying=bool(t.get("flying")),
            link_ok=self.stack.link_ok(),
            x_m=_num(t.get("x"), 0.0),
            y_m=_num(t.get("y"), 0.0),
            yaw_deg=math.degrees(_num(t.get("yaw_rad"), 0.0)),
            visible_markers=tuple(markers),
            ctrl_state=str(t.get("ctrl_state", "")),
            emergency=bool(t.get("emergency")),
            battery_known=bool(t.get("battery_known", True)),
            navdata_doubt=str(t.get("navdata_doubt") or ""),
        )

    def marker_ids(self) -> frozenset[int]:
        return self._markers


def expiry(out: Any) -> Expired | None:
    """The vehicle's ``expired`` in an op's answer (a command it received past its deadline
    and did not run), or None."""
    late = out.get("expired") if isinstance(out, dict) else None
    if not isinstance(late, dict):
        return None
    try:
        return Expired(float(late["age_s"]), float(late["deadline_s"]))
    except (KeyError, TypeError, ValueError):
        log.warning("an expiry that cannot be read in a vehicle's answer: %r", late)
        return None


def _num(value: Any, default: float) -> float:
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return default


class RemoteDialog(DialogManager):
    """``runtime.dialogs[name]`` for a drone in a vehicle process (see the module docstring)."""

    def __init__(
        self,
        graph: Graph,
        settings: Any,
        stack: RemoteDroneStack,
        world: Any,
        describer: DescribePort | None,
        audit: Any,
        *,
        nlu: NLU,
        fleet: FleetPort | None,
        drones: Callable[[], list[str]],
    ) -> None:
        self.stack = stack
        self.task_port = RemoteTaskPort(stack, graph)
        super().__init__(
            graph,
            settings,
            self.task_port,
            RemoteVehicleView(stack, world),
            describer,
            audit,
            time.monotonic,
            nlu=nlu,
            drone=stack.name,
            prefix=stack.prefix,
            fleet=fleet,
            drones=drones,
        )
        self.task_port.on_failure = lambda text: self.announce(text, "warn")
        self._alarms = graph.subscribe(
            names.alarm_topic(stack.name), self._on_alarm, type=names.STRING
        )

    def _on_alarm(self, msg: dict[str, Any]) -> None:
        try:
            alarm = Alarm.from_message(json.loads(str(msg.get("data", ""))))
        except (ValueError, BadAlarm) as exc:
            log.warning("%s: an alarm that cannot be read: %s", self.drone, exc)
            return
        self.hear(alarm)

    async def handle_utterance(
        self,
        text: str,
        confidence: float = 1.0,
        source: str = "text",
        role: str = "pilot",
        issued: float | None = None,
    ) -> DialogResult:
        """As :meth:`DialogManager.handle_utterance`, once the vehicle is there.

        Raises:
            VehicleUnavailable: the vehicle has not joined within ``COMMAND_JOIN_WAIT_S``, is
                not connected, or is silent for ``SILENT_S`` (nothing was sent), or falls
                silent while its commands are answered.
        """
        touch = self.stack.touch_recording
        if touch is not None:  # the recording's id reaches the vehicle before its commands
            touch()
        await self.stack.wait_joined(remote.COMMAND_JOIN_WAIT_S)
        silent = self.stack.silent_for()
        if silent > remote.SILENT_S:
            raise self.stack._unavailable(
                f"is not answering (silent for {silent:.1f} s); nothing was sent"
            )
        return await super().handle_utterance(text, confidence, source, role, issued)

    async def _handle(
        self, text: str, confidence: float, source: str, role: str, issued: float | None = None
    ) -> tuple[DialogResult, str]:
        """As :meth:`DialogManager._handle`; the task ops it sends carry ``issued``, and a
        sentence the vehicle received past its deadline is answered "Not flown" (``expired``)."""
        token = ISSUED.set(issued)
        try:
            return await super()._handle(text, confidence, source, role, issued)
        except CommandExpired as exc:
            late = Expired(exc.age_s, exc.deadline_s)
            reply = not_flown(text, late)
            return DialogResult(reply, exc.commands, False, expired=late), "expired"
        finally:
            ISSUED.reset(token)

    async def _refreshed(self) -> bool:
        return await self.stack.refresh()

    def close(self) -> None:
        self._alarms.close()
        self.task_port.close()


__all__ = ["ISSUED", "RemoteDialog", "RemoteTaskPort", "RemoteVehicleView", "expiry"]
