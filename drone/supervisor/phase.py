"""What the drone is doing, as the supervisor judges it: from the drone's own state and the
task executor's running task (the vehicle knows both; the dialog is not asked)."""

from __future__ import annotations

from enum import StrEnum

from drone.vehicle import VehicleSnapshot


class Phase(StrEnum):
    GROUNDED = "grounded"
    TAKING_OFF = "taking_off"
    AIRBORNE = "airborne"  # flying with nothing to do (or holding a hover)
    EXECUTING = "executing"  # an operator's motion flies (move, turn, goto, patrol)
    WAYPOINTS = "waypoints"  # a plan's waypoints fly (the fleet's, or the supervisor's back-off)
    SEARCHING = "searching"  # a task turns in place looking for markers
    RETURNING = "returning"
    LANDING = "landing"
    EMERGENCY = "emergency"


FLYING = frozenset(
    {
        Phase.TAKING_OFF,
        Phase.AIRBORNE,
        Phase.EXECUTING,
        Phase.WAYPOINTS,
        Phase.SEARCHING,
        Phase.RETURNING,
    }
)
# The operator's motions (the dialog's MOTION): the markers monitor watches only these.
MOTIONS = ("move", "turn", "goto", "patrol")


def phase_of(snap: VehicleSnapshot, task: str = "", task_state: str = "idle") -> Phase:
    """The phase from the snapshot and the running task's name and state (``""``/"idle": none)."""
    if snap.emergency or task == "emergency":
        return Phase.EMERGENCY
    if task == "land" or snap.ctrl_state == "LANDING":
        return Phase.LANDING
    if task == "takeoff" or snap.ctrl_state == "TAKEOFF":
        return Phase.TAKING_OFF
    if not snap.flying:
        return Phase.GROUNDED
    if task == "return_home":
        return Phase.RETURNING
    if task_state == "searching" or task == "search":
        return Phase.SEARCHING
    if task in MOTIONS:
        return Phase.EXECUTING
    if task == "waypoints":
        return Phase.WAYPOINTS
    return Phase.AIRBORNE  # holding a hover, describing, or nothing to do
