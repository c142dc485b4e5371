"""The supervisor: the vehicle's safety monitors, each on its own period, acting on the drone
themselves and publishing what they did as typed alarms (PX4's commander: a table of
conditions → actions beside the flight code; the ground station is told).

A monitor looks at the vehicle's snapshot and the phase of flight and may raise an
:class:`~drone.supervisor.alarms.Alarm`. Monitors latch: an alarm fires once when its condition
starts and re-arms only when it has cleared (with hysteresis for the battery), so the operator
is told once, not every period. An alarm's action preempts the task executor at once (land,
hover and return home bypass its queue); then every listener hears the alarm (the dialog speaks
it, the vehicle publishes it).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from drone.supervisor.alarms import PREEMPTING, ActionKind, Alarm, AlarmAction, Severity
from drone.supervisor.phase import Phase, phase_of
from drone.vehicle import VehicleSnapshot

log = logging.getLogger(__name__)


class Monitor(Protocol):
    """One safety monitor: ``name`` (its alarms' id), ``period_s``, ``check``."""

    name: str
    period_s: float

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> Alarm | None: ...


class Executor(Protocol):
    """What the supervisor needs of the task executor (``server.tasks.TaskManager``)."""

    @property
    def status(self) -> Any: ...  # .name and .state of the running task

    def preempt(self, action: str, *, by: str = "") -> Any: ...

    def submit(self, commands: Sequence[Mapping[str, Any]], *, replace: bool = False) -> Any: ...


def act_on(executor: Executor) -> Callable[[AlarmAction, str], None]:
    """The supervisor's hands on a task executor: stops preempt everything, a descent or a
    back-off replaces what runs."""

    def act(action: AlarmAction, by: str) -> None:
        if action.kind in PREEMPTING:
            executor.preempt(action.kind.value, by=by)
            return
        decisions = executor.submit([action.command()], replace=True)
        if not all(getattr(d, "accepted", True) for d in decisions or ()):
            log.warning("%s: %s refused (%s); hovering", by, action.kind, decisions)
            executor.preempt(ActionKind.HOVER.value, by=by)

    return act


def executor_phase(executor: Executor) -> Callable[[VehicleSnapshot], Phase]:
    """The phase from the snapshot and the executor's running task."""

    def phase(snap: VehicleSnapshot) -> Phase:
        st = executor.status
        return phase_of(snap, str(st.name), str(st.state))

    return phase


_ORDER = {Severity.ALERT: 0, Severity.WARN: 1, Severity.INFO: 2}


@dataclass
class Supervisor:
    """Runs each monitor on its own period; :meth:`step` acts and publishes the alarms due.

    Args:
        monitors: distinct names (periods are kept by name).
        snapshot: the vehicle's latest snapshot.
        phase: the phase of flight for a snapshot (:func:`executor_phase`).
        act: carries out an alarm's action (:func:`act_on`); None: the alarm is told only.
    """

    monitors: Sequence[Monitor]
    snapshot: Callable[[], VehicleSnapshot]
    phase: Callable[[VehicleSnapshot], Phase]
    act: Callable[[AlarmAction, str], None] | None = None
    _due: dict[str, float] = field(default_factory=dict)
    _heard: bool = False  # the drone has answered at least once
    _listeners: list[Callable[[Alarm], None]] = field(default_factory=list)
    history: list[Alarm] = field(default_factory=list)  # the newest last, bounded

    def __post_init__(self) -> None:
        names = [m.name for m in self.monitors]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"safety monitors need distinct names; repeated: {', '.join(dup)}")

    def on_alarm(self, callback: Callable[[Alarm], None]) -> Callable[[], None]:
        """Call ``callback(alarm)`` for every alarm, after its action; returns an unsubscribe."""
        self._listeners.append(callback)
        return lambda: self._listeners.remove(callback)

    @property
    def period_s(self) -> float:
        """The shortest monitor period: how often :meth:`run` steps."""
        return min((m.period_s for m in self.monitors), default=0.25)

    def monitor(self, name: str) -> Monitor:
        """The monitor of that name (KeyError if none)."""
        for m in self.monitors:
            if m.name == name:
                return m
        raise KeyError(name)

    def check(self, snap: VehicleSnapshot, phase: Phase, now: float) -> list[Alarm]:
        """The alarms due at ``now`` for this snapshot, most severe first (nothing acted on)."""
        # Before the first navdata nothing is known (battery 0, link down): no false alarms.
        self._heard = self._heard or snap.link_ok
        if not self._heard:
            return []
        alarms: list[Alarm] = []
        for m in self.monitors:
            due = self._due.get(m.name, now)
            if now + 1e-9 < due:
                continue
            # absolute deadlines: no drift; skip missed periods rather than bursting
            nxt = due + m.period_s
            self._due[m.name] = nxt if nxt > now else now + m.period_s
            alarm = m.check(snap, phase, now)
            if alarm is not None:
                alarms.append(alarm)
        # the most severe first: a critical battery outranks an altitude warning
        return sorted(alarms, key=lambda a: _ORDER[a.severity])

    def step(self, now: float) -> list[Alarm]:
        """Run the monitors due at ``now``: act on each alarm, then tell the listeners."""
        snap = self.snapshot()
        alarms = self.check(snap, self.phase(snap), now)
        for alarm in alarms:
            if alarm.action is not None and self.act is not None:
                self.act(alarm.action, f"{alarm.monitor} monitor")
            self.history.append(alarm)
            del self.history[:-100]
            for cb in list(self._listeners):
                try:
                    cb(alarm)
                except Exception:  # a listener's fault must not stop the next one hearing it
                    log.exception("alarm listener failed on %s", alarm.monitor)
        return alarms

    async def run(self, clock: Callable[[], float]) -> None:
        """Real time: step on absolute deadlines (``clock``: the vehicle's) until cancelled."""
        loop = asyncio.get_running_loop()
        period = self.period_s
        deadline = loop.time()
        while True:
            try:
                self.step(clock())
            except Exception:  # one bad round must not end the supervision
                log.exception("supervisor step failed")
            deadline += period
            await asyncio.sleep(max(0.0, deadline - loop.time()))
