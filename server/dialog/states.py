"""The SNS (voluntary tasks) state machine as data: one Enum and one transition table (h11 style).

Events are the actions of commands (DESIGN §4) the operator gives, and task events reported by
the task manager (took_off, landed, idle, failed, marker_lost, marker_found) or the reset of an
emergency. ``query``, ``describe`` are answered in every state and change nothing; ``cancel``
clears the queue of voluntary tasks.
"""

from __future__ import annotations

from enum import StrEnum

from server.dialog.errors import IllegalTransition


class State(StrEnum):
    LANDED = "LANDED"
    TAKING_OFF = "TAKING_OFF"
    AIRBORNE_IDLE = "AIRBORNE_IDLE"
    EXECUTING = "EXECUTING"
    SEARCHING = "SEARCHING"
    RETURNING = "RETURNING"
    LANDING = "LANDING"
    EMERGENCY = "EMERGENCY"


S = State
MOTION = ("move", "turn", "goto", "patrol")
# Task-manager events that every flying state shares.
_FLYING_COMMON: dict[str, State] = {
    "land": S.LANDING,
    "emergency": S.EMERGENCY,
    "landed": S.LANDED,
    "return_home": S.RETURNING,
    "hover": S.AIRBORNE_IDLE,
    "cancel": S.AIRBORNE_IDLE,
    "idle": S.AIRBORNE_IDLE,
    "failed": S.AIRBORNE_IDLE,
    "landing": S.LANDING,
    **{a: S.EXECUTING for a in MOTION},
    "search": S.SEARCHING,  # tag search on request
}

TRANSITIONS: dict[State, dict[str, State]] = {
    S.LANDED: {
        "takeoff": S.TAKING_OFF,
        "emergency": S.EMERGENCY,
        "landed": S.LANDED,
        "cancel": S.LANDED,
        "took_off": S.AIRBORNE_IDLE,  # someone else (a button) took off
    },
    S.TAKING_OFF: {
        "took_off": S.AIRBORNE_IDLE,
        "land": S.LANDING,
        "emergency": S.EMERGENCY,
        "landed": S.LANDED,
        "failed": S.LANDED,
        "cancel": S.TAKING_OFF,
        "hover": S.TAKING_OFF,
        "return_home": S.TAKING_OFF,
        **{a: S.TAKING_OFF for a in MOTION},  # queued behind the take-off
        "search": S.TAKING_OFF,
    },
    S.AIRBORNE_IDLE: {**_FLYING_COMMON},
    S.EXECUTING: {**_FLYING_COMMON, "marker_lost": S.SEARCHING, "done": S.EXECUTING},
    S.SEARCHING: {**_FLYING_COMMON, "marker_found": S.EXECUTING, "done": S.EXECUTING},
    S.RETURNING: {**_FLYING_COMMON, "done": S.RETURNING, "marker_lost": S.RETURNING},
    S.LANDING: {
        "landed": S.LANDED,
        "takeoff": S.TAKING_OFF,
        "emergency": S.EMERGENCY,
        "land": S.LANDING,
        "cancel": S.LANDING,
    },
    S.EMERGENCY: {"reset": S.LANDED, "emergency": S.EMERGENCY, "cancel": S.EMERGENCY},
}

# Refusals more precise than the state's sentence in states.xml.
REASONS: dict[tuple[State, str], str] = {
    (S.LANDED, "land"): "I am already on the ground.",
    (S.LANDED, "hover"): "I am on the ground; I need to take off first.",
    (S.LANDED, "return_home"): "I am on the ground; I need to take off first.",
    (S.AIRBORNE_IDLE, "takeoff"): "I am already flying.",
    (S.EXECUTING, "takeoff"): "I am already flying.",
    (S.SEARCHING, "takeoff"): "I am already flying.",
    (S.RETURNING, "takeoff"): "I am already flying.",
    (S.TAKING_OFF, "takeoff"): "I am already taking off.",
    (S.LANDING, "hover"): "I am landing; tell me to take off again first.",
}
# Commands answered in place: never a transition.
STATELESS = ("query", "describe", "help")


def next_state(state: State, event: str) -> State:
    """The state after ``event`` in ``state``.

    Raises:
        IllegalTransition: the table has no such transition (reason from REASONS if any).
    """
    nxt = TRANSITIONS[state].get(event)
    if nxt is None:
        reason = REASONS.get((state, event), f"I cannot do that while {describe_state(state)}.")
        raise IllegalTransition(state.value, event, reason)
    return nxt


def describe_state(state: State) -> str:
    """Words for a state ("on the ground", "flying to a marker")."""
    return {
        S.LANDED: "on the ground",
        S.TAKING_OFF: "taking off",
        S.AIRBORNE_IDLE: "hovering",
        S.EXECUTING: "carrying out a task",
        S.SEARCHING: "searching for a marker",
        S.RETURNING: "returning home",
        S.LANDING: "landing",
        S.EMERGENCY: "in emergency mode",
    }[state]


FLYING = frozenset({S.TAKING_OFF, S.AIRBORNE_IDLE, S.EXECUTING, S.SEARCHING, S.RETURNING})
