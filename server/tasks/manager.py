"""``TaskManager``: turns DESIGN §4 commands into tasks, runs them one at a time, searches for
markers when lost, and reports status and events. One per vehicle.

Sans-I/O-ish: nothing here sleeps or opens sockets; time comes in through ``step(now)`` (the
vehicle node calls it at 20 Hz in real time, ``LockstepRig.add_stepper`` every tick in lockstep).

Public API (used by the dialog manager, the REST API and the fleet manager)::

    tm = TaskManager(vehicle, world, clock, search_after_s=1.5, describe_hook=None)
    decisions = tm.submit([{"action": "takeoff"}, {"action": "goto", "marker": 3}])
    #   -> [Decision(command, accepted, reason, task_id)], validated BEFORE anything moves:
    #      unknown marker ids, targets outside the room, not flying → refused with a reason;
    #      if one command is refused, none of the sentence runs.
    tm.cancel()                   # stop the running task and drop the queue; the drone hovers
    tm.preempt("land")            # land / emergency / return_home / hover: now, bypassing the queue
    tm.step(now)                  # advance (arrival rules, tag search, timeouts)
    tm.status                     # TaskStatus(name, state, progress, detail, task_id, queued)
    tm.on_event(cb)               # cb(TaskNotice(kind, text, task, task_id, t)); kinds: started,
                                  # done, failed, cancelled, preempted, searching, marker_found,
                                  # progress (a patrol leg reached)

Queueing: commands of a ``submit`` are appended after the running task (``replace=True``
cancels it and the queue first). A sentence that *starts* with ``land``, ``emergency`` or
``return_home`` preempts at once (DESIGN §5: safety bypasses every queue); later in a sentence
they run in spoken order ("go to marker 3 and land"). ``cancel`` in a sentence cancels;
``query`` is accepted and left to the dialog (it is answered from ``vehicle.snapshot()``).
A manual jog (``vehicle.jog``) cancels the running task.

Tag search: while a task needs localisation (goto and patrol of markers, return home,
indoor waypoints) and no marker has been seen for ``search_after_s``, and the estimate is no
longer confident (planar σ > 0.3 m or yaw σ > 10°) — or at once when the drone has never been
localised, also for a task that only needs a known position (a move, a GPS waypoint) — the
task pauses (state SEARCHING,
event "searching": "I lost sight of the markers, searching"), the drone holds its position and
height and turns in yaw until a marker fix arrives ("marker_found"), then the task resumes.
After two full turns without a marker the task fails.

Idle search (``idle_search=True``): flying indoors with nothing to do, no
marker for ``search_after_s`` and the estimate no longer confident, the manager starts a
``search`` task itself (event "searching": "My position is uncertain; searching for markers"),
which reports what it found or gives up after two turns. Not within ``IDLE_JOG_GRACE_S`` of a
manual jog (the operator is flying by hand), and once per uncertainty: after a search that found
nothing it waits for the next marker fix before searching again.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from dataclasses import replace as dataclass_replace
from typing import Any

from pydantic import BaseModel

from drone.commands import Command, parse_command, wire
from drone.control.clock import Clock
from drone.control.pid import Setpoint
from drone.limits import limits_of
from drone.supervisor.people import KeepAway
from drone.vehicle import Vehicle, VehicleSnapshot
from server.tasks.base import ArrivalRule, Context, Outcome, PlanState, Task
from server.tasks.build import build_task
from server.tasks.errors import CommandError, IllegalTransition, RefusedError
from server.tasks.legs import LegsTask
from server.tasks.search import SEARCH_MAX_TURNS, SEARCH_RATE_RAD_S
from server.tasks.states import TaskEvent, TaskState, transition

log = logging.getLogger(__name__)

SAFETY_ACTIONS = ("land", "emergency", "return_home", "hover")
LOST_SIGMA_M = 0.3
LOST_SIGMA_YAW_RAD = math.radians(10.0)
IDLE_JOG_GRACE_S = 5.0  # no idle search this soon after the operator's last jog


@dataclass(frozen=True)
class Decision:
    """The answer to one submitted command."""

    command: dict[str, Any]
    accepted: bool
    reason: str  # why refused, or what will happen
    task_id: int | None = None
    question: bool = False  # refused with a question to the operator ("Which chair?")


@dataclass(frozen=True)
class TaskStatus:
    """What ``/uav/task`` carries (uav_console/TaskStatus)."""

    name: str  # "" when idle
    state: str  # a TaskState value, or "idle"
    progress: float  # 0..1
    detail: str
    task_id: int | None = None
    queued: int = 0

    def as_message(self, drone: str = "") -> dict[str, Any]:
        return {
            "drone": drone,
            "name": self.name,
            "state": self.state,
            "progress": self.progress,
            "detail": self.detail,
        }


@dataclass(frozen=True)
class TaskNotice:
    """An event for the dialog and the console."""

    kind: str
    text: str
    task: str
    task_id: int | None
    t: float


class TaskManager(Context):
    """See the module docstring."""

    def __init__(
        self,
        vehicle: Vehicle,
        world: Any,
        clock: Clock,
        *,
        search_after_s: float = 1.5,
        arrival: ArrivalRule | None = None,
        describe_hook: Callable[[VehicleSnapshot], str] | None = None,
        margin_m: float | None = None,
        ceiling_m: float | None = None,
        idle_search: bool = False,
        keep_away: KeepAway | None = None,
    ) -> None:
        self.vehicle = vehicle
        # where people are and how far to keep from them (drone/supervisor/people.py): a
        # target too close is refused when planned, a leg passing too close is re-routed
        self.keep_away = keep_away
        self.world = world
        self.clock = clock
        self.search_after_s = search_after_s
        self.arrival = arrival or ArrivalRule()
        self.describe_hook = describe_hook
        # the world's limits (drone/limits.py); ``margin_m``/``ceiling_m`` may only tighten them
        lim = limits_of(world)
        if margin_m is not None:
            lim = dataclass_replace(lim, wall_margin_m=max(margin_m, 0.0))
        if ceiling_m is not None:
            lim = dataclass_replace(lim, ceiling_m=min(ceiling_m, lim.ceiling_m))
        self.limits = lim
        self.margin_m = lim.wall_margin_m
        self.ceiling_m = lim.ceiling_m
        self._lock = threading.RLock()
        self._queue: deque[Task] = deque()
        self._current: Task | None = None
        self._listeners: list[Callable[[TaskNotice], None]] = []
        self._pending: list[TaskNotice] = []
        self.history: deque[tuple[Task, str]] = deque(maxlen=50)
        self._search_started: float | None = None
        self._search_marker_t: float | None = None
        self._last_now: float | None = None
        self.idle_search = idle_search
        self._last_jog = -math.inf
        self._idle_searched_at_fix: float | None = None  # the fix before the last idle search
        vehicle.add_jog_listener(self._on_jog)

    # ------------------------------------------------------------------ Context
    def snapshot(self) -> VehicleSnapshot:
        snap: VehicleSnapshot = self.vehicle.snapshot()
        return snap

    def emit(self, kind: str, text: str) -> None:
        cur = self._current
        self._pending.append(
            TaskNotice(
                kind, text, cur.name if cur else "", cur.id if cur else None, self.clock.now()
            )
        )

    # ------------------------------------------------------------------ public
    def on_event(self, cb: Callable[[TaskNotice], None]) -> None:
        """Call ``cb(notice)`` for every event (from the thread that caused it)."""
        self._listeners.append(cb)

    @property
    def current(self) -> Task | None:
        return self._current

    @property
    def queued(self) -> tuple[Task, ...]:
        return tuple(self._queue)

    @property
    def status(self) -> TaskStatus:
        cur = self._current
        if cur is None:
            return TaskStatus("", "idle", 0.0, "", None, len(self._queue))
        return TaskStatus(
            cur.name, cur.state.value, cur.progress, cur.detail, cur.id, len(self._queue)
        )

    def submit(
        self, commands: Sequence[Command | Mapping[str, Any]], *, replace: bool = False
    ) -> list[Decision]:
        """Validate ``commands`` (a sentence: typed commands or their JSON objects) and queue
        them; see the module docstring."""
        with self._lock:
            out, tasks = self._validate(list(commands))
            if not all(d.accepted for d in out):
                first = next(d for d in out if not d.accepted)
                return [
                    d if not d.accepted else Decision(d.command, False, f"not run: {first.reason}")
                    for d in out
                ]
            items = list(zip(out, tasks, strict=True))
            head = items[0][1] if items else None
            if head is not None and head.name in ("land", "emergency", "return_home"):
                items = items[1:]
                self._preempt_with(head)
            elif replace:
                self._cancel_all("replaced by a new command", TaskEvent.CANCEL)
            for d, task in items:
                if d.command.get("action") == "cancel":
                    self._cancel_all("cancelled", TaskEvent.CANCEL)
                elif task is not None:
                    self._queue.append(task)
        self._flush()
        return out

    def _validate(
        self, commands: list[Command | Mapping[str, Any]]
    ) -> tuple[list[Decision], list[Task | None]]:
        s = self.snapshot()
        flying = s.flying or s.ctrl_state == "TAKEOFF"
        p = self._predicted(s, flying)
        decisions: list[Decision] = []
        tasks: list[Task | None] = []
        for raw in commands:
            if isinstance(raw, Mapping):
                cmd = dict(raw)
            elif isinstance(raw, BaseModel):  # a typed command: as said, unstated slots omitted
                cmd = wire(parse_command(raw))
            else:
                cmd = {"action": repr(raw)}
            action = cmd.get("action")
            if action in ("cancel", "query"):
                text = "cancelling" if action == "cancel" else "answered from telemetry"
                decisions.append(Decision(cmd, True, text))
                tasks.append(None)
                if action == "cancel":
                    p = self._predicted(s, flying)
                continue
            try:
                task = build_task(cmd)
                before, p = p, task.plan(p, self)
                self._check_people(before, p)
            except CommandError as exc:
                ask = bool(getattr(exc, "question", False))
                decisions.append(Decision(cmd, False, exc.reason, question=ask))
                tasks.append(None)
                continue
            decisions.append(Decision(cmd, True, f"queued: {task.describe()}", task.id))
            tasks.append(task)
        return decisions, tasks

    def _check_people(self, before: PlanState, after: PlanState) -> None:
        """Refuse a flight whose target lies too close to a person (keep_away)."""
        moved = (after.x, after.y) != (before.x, before.y)
        if self.keep_away is None or not (after.flying and after.located and moved):
            return
        why = self.keep_away.target_refusal(after.x, after.y)
        if why is not None:
            raise RefusedError(why[:1].upper() + why[1:] + ".")

    def _predicted(self, s: VehicleSnapshot, flying: bool) -> PlanState:
        """The state the next queued task will start from (after the running and queued ones)."""
        p = PlanState(flying, s.x, s.y, max(s.z, 0.0), s.yaw_rad, located=s.localised)
        for t in ([self._current] if self._current else []) + list(self._queue):
            if t.name == "patrol":
                continue  # loops forever; what follows starts wherever it is cancelled
            try:
                p = t.plan(p, self)
            except CommandError:  # no longer plannable (e.g. landed meanwhile): skip its effect
                continue
        return p

    def cancel(self, reason: str = "cancelled", *, hold: bool = True) -> bool:
        """Cancel the running task and the queue. True if there was any.

        ``hold``: the drone holds its position (a setpoint where it is, or the drone's own
        hover when not localised); False leaves the vehicle's control as it is (a jog).
        """
        with self._lock:
            had = self._current is not None or bool(self._queue)
            self._cancel_all(reason, TaskEvent.CANCEL, hold=hold)
        self._flush()
        return had

    def preempt(self, action: str, *, by: str = "") -> Decision:
        """Run a safety action now: ``land``, ``emergency``, ``return_home`` or ``hover``.

        Everything running or queued is preempted. Refused (with a reason) only when the action
        is not one of these or cannot be planned (e.g. return home with no station). ``by``
        names what acted when it was not the operator (a safety monitor, the central server's
        silence): the preempted tasks' reason says so ("preempted by hover (central server
        silent)"), and the fleet's LTM tells an automatic action from the operator's by it.
        """
        cmd = {"action": action}
        if action not in SAFETY_ACTIONS:
            return Decision(
                cmd, False, f"{action!r} is not a safety action ({', '.join(SAFETY_ACTIONS)})"
            )
        with self._lock:
            try:
                task = build_task(cmd)
                s = self.snapshot()
                if action in ("return_home", "hover"):
                    task.plan(
                        PlanState(s.flying, s.x, s.y, s.z, s.yaw_rad, located=s.localised), self
                    )
            except CommandError as exc:
                return Decision(cmd, False, exc.reason)
            self._preempt_with(task, by)
        self._flush()
        return Decision(cmd, True, f"now: {task.describe()}", task.id)

    def _preempt_with(self, task: Task, by: str = "") -> None:
        why = f"preempted by {task.name}" + (f" ({by})" if by else "")
        self._cancel_all(why, TaskEvent.PREEMPT)
        self._queue.appendleft(task)
        # Land and emergency reach the wire now, not at the next step (DESIGN §5).
        self._start_next(self.clock.now())

    def step(self, now: float) -> TaskStatus:
        """Advance the running task; start the next one when it ends. Returns the status."""
        with self._lock:
            self._last_now = now
            if self._current is None and self._queue:
                self._start_next(now)
            cur = self._current
            if cur is not None:
                self._supervise(cur, now)
            elif self.idle_search and not self._queue:
                self._maybe_idle_search(now)
        self._flush()
        return self.status

    # ------------------------------------------------------------------ internals
    def _maybe_idle_search(self, now: float) -> None:
        """Start a tag search when hovering idle with an uncertain pose (module docstring)."""
        world = self.world
        if not (getattr(world, "indoor", False) and getattr(world, "markers", ())):
            return
        s = self.snapshot()
        if not s.flying or s.ctrl_state not in ("HOVERING", "FLYING") or not s.localised:
            return
        if now - self._last_jog < IDLE_JOG_GRACE_S:
            return
        if self._idle_searched_at_fix is not None and s.last_marker_t == self._idle_searched_at_fix:
            return  # searched already and found nothing since: do not spin for ever
        if not self._lost(s, now):
            return
        self._idle_searched_at_fix = s.last_marker_t
        self.emit("searching", "My position is uncertain; searching for markers")
        self._queue.append(build_task({"action": "search"}))
        self._start_next(now)

    def _on_jog(self) -> None:
        self._last_jog = self.clock.now()
        if self._current is not None or self._queue:
            self.cancel("manual control took over", hold=False)

    def _cancel_all(self, reason: str, event: TaskEvent, hold: bool = True) -> None:
        kind = "cancelled" if event is TaskEvent.CANCEL else "preempted"
        for t in list(self._queue):
            t.state = transition(t.state, event)
            self.history.append((t, reason))
        self._queue.clear()
        cur = self._current
        if cur is not None:
            cur.state = transition(cur.state, event)
            cur.result = reason
            self.emit(kind, f"{cur.describe()}: {reason}")
            self.history.append((cur, reason))
            self._current = None
            self._search_started = None
            if hold and event is TaskEvent.CANCEL and cur.name not in ("land", "emergency"):
                s = self.snapshot()
                if s.flying:
                    if s.localised:
                        self.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad))
                    else:
                        self.vehicle.hover()

    def _start_next(self, now: float) -> None:
        while self._current is None and self._queue:
            task = self._queue.popleft()
            task.state = transition(task.state, TaskEvent.START)
            self._current = task
            self._search_started = None
            self.emit("started", task.describe())
            try:
                out = task.start(self, now)
            except CommandError as exc:
                out = Outcome(False, exc.reason)
            if out is not None:
                self._finish(task, out)

    def _finish(self, task: Task, out: Outcome) -> None:
        event = TaskEvent.SUCCEED if out.ok else TaskEvent.FAIL
        try:
            task.state = transition(task.state, event)
        except IllegalTransition:
            log.exception("task %s", task.name)
        task.result = out.text
        self.emit("done" if out.ok else "failed", out.text)
        self.history.append((task, out.text))
        if self._current is task:
            self._current = None
            self._search_started = None
        if not out.ok:
            # a failure leaves the drone holding position; later tasks of that plan are dropped
            for t in list(self._queue):
                t.state = transition(t.state, TaskEvent.CANCEL)
            self._queue.clear()

    def _needs_search(self, task: Task, s: VehicleSnapshot, now: float) -> bool:
        if not s.flying:
            return False
        if task.needs_localisation:
            return self._lost(s, now)
        return task.needs_position and not s.localised

    def _lost(self, s: VehicleSnapshot, now: float) -> bool:
        """No usable position: never localised, or no marker lately and no confidence left."""
        if not s.localised:
            return True  # never seen a marker: do not fly anywhere on a made-up position
        since = s.last_marker_t
        stale = since is None or now - since > self.search_after_s
        unsure = (
            not s.localised
            or s.position_sigma_m > LOST_SIGMA_M
            or s.yaw_sigma_rad > LOST_SIGMA_YAW_RAD
        )
        return stale and unsure

    def _supervise(self, task: Task, now: float) -> None:
        s = self.snapshot()
        if task.state is TaskState.SEARCHING:
            assert self._search_started is not None
            found = s.last_marker_t is not None and s.last_marker_t != self._search_marker_t
            if found and s.localised:
                task.state = transition(task.state, TaskEvent.FOUND)
                ids = ", ".join(str(m.id) for m in s.markers) or "?"
                self.emit("marker_found", f"Found marker {ids}; carrying on")
                if isinstance(task, LegsTask):
                    task.pause(now - self._search_started)
                if task.target is not None:
                    self.vehicle.set_setpoint(task.target)
                else:  # its setpoints come from the position just found: hold here until then
                    self.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad))
                task.detail = task.detail.replace(" (searching)", "")
                self._search_started = None
                return
            if now - self._search_started > SEARCH_MAX_TURNS * 2 * math.pi / SEARCH_RATE_RAD_S:
                self._finish(task, Outcome(False, "I lost the markers and could not find one"))
            return
        if self._needs_search(task, s, now):
            task.state = transition(task.state, TaskEvent.LOST)
            self._search_started = now
            self._search_marker_t = s.last_marker_t
            task.detail += " (searching)"
            self.emit("searching", "I lost sight of the markers, searching")
            self.vehicle.set_setpoint(Setpoint(s.x, s.y, s.z, s.yaw_rad, SEARCH_RATE_RAD_S))
            return
        try:
            out = task.step(self, now)
        except CommandError as exc:
            out = Outcome(False, exc.reason)
        if out is not None:
            self._finish(task, out)
            if self._queue:
                self._start_next(now)

    def _flush(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, []
        for n in pending:
            for cb in list(self._listeners):
                try:
                    cb(n)
                except Exception:
                    log.exception("task event listener failed")
