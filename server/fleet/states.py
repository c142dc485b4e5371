"""Mission states and the one transition table (h11 style: state -> {event: next state}).

Every part that says what a mission is doing reads it from here: the CTM (``ctm.py``), the REST
doors (``GET /missions/{id}``, ``GET /patrol``), the dialog and the console's Central panel.
A fleet that replicates the CTM's state replicates these values.

::

    WAITING ──on_route──▶ RUNNING ──off_route──▶ WAITING      (a drone reaches / leaves the route)
    WAITING, RUNNING ──stall──▶ STALLED ──ready──▶ WAITING    (no drone able to fly, then one)
    WAITING, RUNNING, STALLED ──operator──▶ PAUSED ──resume──▶ WAITING
    any but ENDED ──end──▶ ENDED
"""

from __future__ import annotations

import enum

from server.fleet.errors import IllegalTransition


class MissionState(enum.Enum):
    """What a mission is doing (the ``state`` of ``GET /missions/{id}``)."""

    WAITING = "waiting"  # no drone on the route yet: one is on its way (or none has joined)
    RUNNING = "running"  # a drone patrols the route
    # the operator took one of its drones (land, hover, stop, emergency, a jog) or paused it, or
    # a drone's safety monitor holds it asking the operator (navdata in doubt, out of the
    # geofence): the CTM sends its drones nothing until the operator resumes or ends it
    PAUSED = "paused"
    STALLED = "stalled"  # nobody on the route and no drone able to fly it: resumes by itself
    ENDED = "ended"  # ended by the operator; its drones flew home

    @property
    def live(self) -> bool:
        """Not ended: the mission still holds its drones and may fly again."""
        return self is not MissionState.ENDED

    @property
    def flying(self) -> bool:
        """The CTM runs it (dispatches, hands over): waiting or running."""
        return self in (MissionState.WAITING, MissionState.RUNNING)


class MissionEvent(enum.Enum):
    ON_ROUTE = "on_route"  # a drone of the mission reached the route
    OFF_ROUTE = "off_route"  # no drone of the mission on the route any more
    OPERATOR = "operator"  # the operator took one of its drones, or paused it
    RESUME = "resume"  # the operator resumes it
    STALL = "stall"  # no drone on the route and none able to fly
    READY = "ready"  # a drone able to fly it again
    END = "end"  # the operator ends it


S, E = MissionState, MissionEvent
TRANSITIONS: dict[MissionState, dict[MissionEvent, MissionState]] = {
    S.WAITING: {E.ON_ROUTE: S.RUNNING, E.STALL: S.STALLED, E.OPERATOR: S.PAUSED, E.END: S.ENDED},
    S.RUNNING: {E.OFF_ROUTE: S.WAITING, E.STALL: S.STALLED, E.OPERATOR: S.PAUSED, E.END: S.ENDED},
    S.STALLED: {E.READY: S.WAITING, E.OPERATOR: S.PAUSED, E.END: S.ENDED},
    S.PAUSED: {E.RESUME: S.WAITING, E.OPERATOR: S.PAUSED, E.END: S.ENDED},
    S.ENDED: {},
}

# How the operator's words name the events they may cause (REST ``action``, the dialog).
VERBS = {"pause": E.OPERATOR, "resume": E.RESUME, "end": E.END}


def transition(state: MissionState, event: MissionEvent) -> MissionState:
    """The state after ``event``.

    Raises:
        IllegalTransition: ``event`` is not allowed in ``state`` (the message says both).
    """
    try:
        return TRANSITIONS[state][event]
    except KeyError:
        raise IllegalTransition(
            f"a mission cannot {event.value.replace('_', ' ')} while {state.value}"
        ) from None
