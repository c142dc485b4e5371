"""In-memory fakes that behave like the task manager, the vehicle and the captioner.

FakeFlight is a tiny lockstep world: commands queue, the running one completes after a fixed
virtual duration, take-off/landing change ``flying`` and altitude, the battery drains with time.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from server.dialog.ports import DroneView, TaskDecision, TaskReport


@dataclass
class FakeFlight:
    markers: frozenset[int] = frozenset({1, 2, 3, 4, 5})
    battery_pct: float = 80.0
    drain_pct_per_s: float = 0.0
    task_s: float = 2.0
    snap: DroneView = field(default_factory=lambda: DroneView(80.0, 0.0, False))
    queue: list[dict[str, Any]] = field(default_factory=list)
    running: dict[str, Any] | None = None
    started: float = 0.0
    now: float = 0.0
    log: list[tuple[str, Any]] = field(default_factory=list)
    _callbacks: list[Callable[[TaskReport], None]] = field(default_factory=list)

    # TaskPort
    def submit(self, commands: Sequence[Mapping[str, Any]]) -> list[TaskDecision]:
        out = []
        for c in commands:
            if c["action"] == "goto" and c["marker"] not in self.markers:
                out.append(TaskDecision(False, f"There is no marker {c['marker']}."))
                continue
            self.queue.append(dict(c))
            self.log.append(("submit", dict(c)))
            out.append(TaskDecision(True))
        return out

    def cancel(self) -> None:
        self.log.append(("cancel", None))
        self.queue.clear()
        self.running = None

    def preempt(self, command: Mapping[str, Any], by: str = "") -> None:
        self.log.append(("preempt", dict(command)))
        self.queue.clear()
        self.running = None
        if command["action"] == "emergency":
            self.snap = replace(self.snap, flying=False, altitude_m=0.0)
        else:
            self.queue.append(dict(command))

    def on_event(self, callback: Callable[[TaskReport], None]) -> None:
        self._callbacks.append(callback)

    def _emit(self, kind: str, cmd: Mapping[str, Any] | None = None) -> None:
        for cb in self._callbacks:
            cb(TaskReport(kind, dict(cmd or {})))

    # VehiclePort
    def snapshot(self) -> DroneView:
        return replace(self.snap, battery_pct=self.battery_pct)

    def marker_ids(self) -> frozenset[int]:
        return self.markers

    # lockstep
    def step(self, now: float) -> None:
        dt = now - self.now
        self.now = now
        if self.snap.flying:
            self.battery_pct = max(0.0, self.battery_pct - self.drain_pct_per_s * dt)
        if self.running is None and self.queue:
            self.running = self.queue.pop(0)
            self.started = now
            self._emit("started", self.running)
        if self.running is not None and now - self.started >= self.task_s:
            cmd, self.running = self.running, None
            a = cmd["action"]
            if a == "takeoff":
                self.snap = replace(self.snap, flying=True, altitude_m=1.0)
                self._emit("took_off", cmd)
            elif a == "land":
                self.snap = replace(self.snap, flying=False, altitude_m=0.0)
                self._emit("landed", cmd)
            elif a == "move" and cmd.get("direction") in ("up", "down"):
                d = cmd.get("distance", 0.5) * (1 if cmd["direction"] == "up" else -1)
                self.snap = replace(self.snap, altitude_m=self.snap.altitude_m + d)
                self._emit("done", cmd)
            else:
                self._emit("done", cmd)
            if not self.queue and self.snap.flying:
                self._emit("idle")


class FakeDescriber:
    def __init__(self, text: str = "A room with a red marker on the wall.") -> None:
        self.text = text
        self.calls = 0

    async def describe(self) -> str:
        self.calls += 1
        return self.text


class FakeStore:
    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def append(self, **kw: Any) -> int:
        self.rows.append(kw)
        return len(self.rows)
