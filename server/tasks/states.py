"""Task states and the one transition table (h11 style: state -> {event: next state})."""

from __future__ import annotations

import enum

from server.tasks.errors import IllegalTransition


class TaskState(enum.Enum):
    QUEUED = "queued"
    RUNNING = "running"
    SEARCHING = "searching"  # lost the markers: turning in place until one is seen (tag search)
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"
    PREEMPTED = "preempted"  # a safety action (land, emergency, return home) took over

    @property
    def terminal(self) -> bool:
        return self in TERMINAL


class TaskEvent(enum.Enum):
    START = "start"
    LOST = "lost"  # no marker for search_after_s while localisation is needed
    FOUND = "found"  # a marker fix again
    SUCCEED = "succeed"
    FAIL = "fail"
    CANCEL = "cancel"
    PREEMPT = "preempt"


S, E = TaskState, TaskEvent
TRANSITIONS: dict[TaskState, dict[TaskEvent, TaskState]] = {
    S.QUEUED: {E.START: S.RUNNING, E.CANCEL: S.CANCELLED, E.PREEMPT: S.PREEMPTED},
    S.RUNNING: {
        E.LOST: S.SEARCHING,
        E.SUCCEED: S.SUCCEEDED,
        E.FAIL: S.FAILED,
        E.CANCEL: S.CANCELLED,
        E.PREEMPT: S.PREEMPTED,
    },
    S.SEARCHING: {
        E.FOUND: S.RUNNING,
        E.FAIL: S.FAILED,
        E.CANCEL: S.CANCELLED,
        E.PREEMPT: S.PREEMPTED,
    },
    S.SUCCEEDED: {},
    S.FAILED: {},
    S.CANCELLED: {},
    S.PREEMPTED: {},
}
TERMINAL = frozenset(s for s, t in TRANSITIONS.items() if not t)


def transition(state: TaskState, event: TaskEvent) -> TaskState:
    """The state after ``event``.

    Raises:
        IllegalTransition: ``event`` is not allowed in ``state``.
    """
    try:
        return TRANSITIONS[state][event]
    except KeyError:
        raise IllegalTransition(f"task cannot {event.value} while {state.value}") from None
