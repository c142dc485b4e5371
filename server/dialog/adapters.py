"""Adapters from the real parts to the dialog ports: server.tasks.TaskManager and drone.Vehicle.

The task manager speaks ``TaskNotice(kind, text, task, ...)`` and ``preempt(action: str)``; the
vehicle's snapshot is richer than the dialog needs. These adapters translate, nothing more.
"""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

from drone.vehicle import Vehicle
from server.dialog.ports import DroneView, TaskDecision, TaskReport

SAFETY_ACTIONS = ("land", "emergency", "return_home", "hover")


class TaskManagerPort:
    """server.tasks.TaskManager as a :class:`~server.dialog.ports.TaskPort`."""

    def __init__(self, tm: Any) -> None:
        self.tm = tm

    def submit(self, commands: Sequence[Mapping[str, Any]]) -> list[TaskDecision]:
        return [
            TaskDecision(bool(d.accepted), str(d.reason), bool(getattr(d, "question", False)))
            for d in self.tm.submit(commands)
        ]

    def cancel(self) -> None:
        self.tm.cancel()

    def preempt(self, command: Mapping[str, Any], by: str = "") -> None:
        action = str(command.get("action", ""))
        if action in SAFETY_ACTIONS and len(command) == 1:
            self.tm.preempt(action, by=by)
        else:  # e.g. the ANS altitude ceiling: "move down 0.4 m" replacing everything
            self.tm.submit([dict(command)], replace=True)

    def on_event(self, callback: Callable[[TaskReport], None]) -> None:
        def translate(notice: Any) -> None:
            for event in task_events(str(notice.kind), str(notice.task or ""), notice.text):
                callback(event)
                status = self.tm.status
                if (
                    event.kind in ("done", "failed", "took_off")
                    and status.state == "idle"
                    and not status.queued
                ):
                    callback(TaskReport("idle"))

        self.tm.on_event(translate)


def task_events(kind: str, task: str, text: str | None) -> list[TaskReport]:
    """A task manager's notice (its ``kind`` and ``task``) as the dialog's events: none for
    a cancelled or preempted task (the dialog made that change itself), else one."""
    cmd = {"action": task} if task else {}
    if kind == "done" and task == "takeoff":
        kind = "took_off"
    elif kind == "done" and task in ("land", "emergency"):
        kind = "landed"
    elif kind == "started" and task == "land":
        kind = "landing"
    elif kind == "searching":
        kind = "marker_lost"
    elif kind in ("cancelled", "preempted"):
        return []
    return [TaskReport(kind, cmd, str(text or ""))]


class VehicleAdapter:
    """A :class:`drone.vehicle.Vehicle` (+ its world) as a dialog's
    :class:`~server.dialog.ports.VehiclePort`."""

    def __init__(self, vehicle: Vehicle, world: Any) -> None:
        self.vehicle = vehicle
        self._markers = frozenset(int(m.id) for m in getattr(world, "markers", ()))

    def snapshot(self) -> DroneView:
        s = self.vehicle.snapshot()
        return DroneView(
            battery_pct=float(s.battery_pct),
            altitude_m=float(s.altitude_m),
            flying=bool(s.flying),
            link_ok=bool(s.link_ok),
            x_m=float(s.x),
            y_m=float(s.y),
            yaw_deg=math.degrees(float(s.yaw_rad)),
            visible_markers=tuple(int(m.id) for m in s.markers),
            ctrl_state=str(s.ctrl_state),
            emergency=bool(s.emergency),
            battery_known=bool(getattr(s, "battery_known", True)),
            navdata_doubt=str(getattr(s, "navdata_doubt", "")),
        )

    def marker_ids(self) -> frozenset[int]:
        return self._markers


class CallableDescriber:
    """Any ``async fn() -> str | (str, score)`` (e.g. ``lambda: runtime.describe("uav1")``) as a
    :class:`~server.dialog.ports.DescribePort`."""

    def __init__(self, fn: Callable[[], Awaitable[Any]]) -> None:
        self.fn = fn

    async def describe(self) -> str:
        out = await self.fn()
        return str(out[0] if isinstance(out, tuple) else out)
