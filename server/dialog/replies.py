"""Short natural sentences for the operator (spoken by the browser: keep them brief)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from server.dialog.ports import DroneView
from server.dialog.states import State, describe_state

LOW_CONFIDENCE = "Sorry, I am not sure I heard that right. Could you repeat or rephrase?"
NOT_UNDERSTOOD = "Sorry, I did not understand. Could you rephrase?"
# A signed amount ("go forward -5 meters") is refused, never flown with its sign dropped.
NEGATIVE_AMOUNT = (
    "I do not fly negative distances or angles. Say the direction instead, "
    "for example 'go back 5 meters'."
)
OBSERVER = "Only the pilot may command the drone."


def _qty(value: float, unit: str) -> str:
    text = f"{value:g}"
    plural = "" if value == 1 else "s"
    return f"{text} {unit}{plural}"


# The whole fleet's patrol (server/fleet/central.py), read back before it runs.
FLEET_WORDS = {
    "patrol_start": "Starting the patrol with all drones",
    "patrol_stop": "Ending the patrol",
    "patrol_pause": "Pausing the patrol",
    "patrol_resume": "Resuming the patrol",
}


def confirmation(cmd: Mapping[str, Any]) -> str:
    """What the drone is about to do, with the understood values ("Climbing 1 meter")."""
    a = cmd.get("action")
    if a in FLEET_WORDS:
        return FLEET_WORDS[str(a)]
    if a == "takeoff":
        return "Taking off"
    if a == "land":
        return "Landing"
    if a == "hover":
        return "Holding position"
    if a == "emergency":
        return "Emergency: cutting the motors"
    if a == "return_home":
        return "Returning home to land there"
    if a == "cancel":
        return "Cancelled"
    if a == "move":
        d = cmd.get("direction", "")
        verb = {"up": "Climbing", "down": "Descending"}.get(d, f"Moving {d}")
        dist = cmd.get("distance")
        return f"{verb} {_qty(dist, 'meter')}" if dist is not None else verb
    if a in ("goto", "turn") and "object" in cmd and "marker" not in cmd:
        what = object_words(cmd)
        return f"Flying to {what}" if a == "goto" else f"Turning to face {what}"
    if a == "search":
        return "Searching for markers"
    if a == "turn":
        d, ang = cmd.get("direction"), cmd.get("angle")
        if d is None and ang == 180:
            return "Turning around"
        words = (
            ["Turning"] + ([d] if d else []) + ([_qty(ang, "degree")] if ang is not None else [])
        )
        return " ".join(words)
    if a == "goto":
        return f"Flying to {target_words(cmd)}"
    if a == "patrol":
        kind = "waypoints" if not cmd.get("markers") and cmd.get("waypoints") else "markers"
        ms = cmd.get(kind)
        if not ms:
            return "Starting the patrol"
        return f"Patrolling {kind} {join_and([str(m) for m in ms])}"
    return str(a)


def target_words(cmd: Mapping[str, Any]) -> str:
    """ "marker 3" or "waypoint 3": what a goto flies to."""
    if "marker" not in cmd and "waypoint" in cmd:
        return f"waypoint {cmd.get('waypoint')}"
    return f"marker {cmd.get('marker')}"


def object_words(cmd: Mapping[str, Any]) -> str:
    """ "the red chair", "the nearest window", "the door" from a command's object slots."""
    words = [str(cmd[k]) for k in ("which", "colour", "object") if cmd.get(k)]
    return "the " + " ".join(words)


def result(cmd: Mapping[str, Any]) -> str:
    """A finished task ("Reached marker 3")."""
    a = cmd.get("action")
    if a == "goto":
        return f"Reached {target_words(cmd)}."
    if a == "takeoff":
        return "I am airborne."
    if a == "land":
        return "Landed."
    if a == "return_home":
        return "I am back home."
    if a == "patrol":
        return "Patrol finished."
    if a == "move":
        return "Done moving."
    if a == "turn":
        return "Done turning."
    return "Done."


def plan(cmds: Sequence[Mapping[str, Any]]) -> str:
    """Confirmations of a whole sentence: "Taking off, then flying to marker 2, then landing."."""
    parts = [confirmation(c) for c in cmds]
    text = ", then ".join([parts[0]] + [p[:1].lower() + p[1:] for p in parts[1:]])
    return text + "."


def join_and(items: Sequence[str]) -> str:
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def answer(item: str, snap: DroneView, state: State) -> str:
    """A status answer with numbers ("Battery is at 76 percent")."""
    if item == "battery":
        return f"Battery is at {snap.battery_pct:.0f} percent."
    if item == "altitude":
        if not snap.flying:
            return "I am on the ground."
        return f"I am at {snap.altitude_m:.1f} meters."
    if item == "position":
        near = f", near marker {snap.visible_markers[0]}" if snap.visible_markers else ""
        return (
            f"I am at x {snap.x_m:.1f}, y {snap.y_m:.1f} meters, "
            f"heading {snap.yaw_deg:.0f} degrees{near}."
        )
    link = "" if snap.link_ok else " The link to the drone is lost."
    return f"I am {describe_state(state)}; battery {snap.battery_pct:.0f} percent.{link}"


def unknown_marker(marker: int) -> str:
    return f"There is no marker {marker}."
