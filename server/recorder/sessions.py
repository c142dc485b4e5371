"""Where a flight session starts and ends (sans-I/O: fed messages and times, nothing else).

A flight session is one stretch of operating the drones, and one recording:

- it **starts** when any drone is airborne (an ``ardrone_autonomy/Navdata`` state other than
  landed/default/init/test — ardrone_autonomy's ``state`` is the AR.Drone's major control state:
  2 LANDED, 3 FLYING, 4 HOVERING, 6 TAKEOFF, 7 GOTOFIX, 8 LANDING, 9 LOOPING — or a MAVROS
  ``/mavros/state`` with ``armed``), or when an operator's command is audited (``touch``), so the
  "take off" that begins a flight is inside its recording;
- it **ends** when no drone has been airborne and no command came for ``idle_s`` seconds.

A fleet is one session: every drone's topics go to the same recording, which lasts from the
first take-off to ``idle_s`` after the last landing. The few seconds before the start are in
the recording too (the recorder keeps a pre-roll buffer), and so is the latest message of every
topic, so a replay starts with the dialog state, task and map already known.
"""

from __future__ import annotations

from enum import Enum
from typing import Any

AIRBORNE_STATES = frozenset({3, 4, 6, 7, 8, 9})  # ardrone_autonomy Navdata.state (see above)


class Change(Enum):
    START = "start"
    END = "end"


def drone_of(topic: str) -> str | None:
    """The drone a vehicle topic belongs to: ``/uav2/ardrone/navdata`` -> uav2, a single
    drone's ``/ardrone/navdata`` -> uav1 (DESIGN §4: a fleet prefixes ``/NAME``)."""
    for marker in ("/ardrone/navdata", "/mavros/state"):
        if topic.endswith(marker):
            prefix = topic[: -len(marker)].strip("/")
            return prefix or "uav1"
    return None


class FlightDetector:
    """Decides when recordings start and end; see the module docstring."""

    def __init__(self, idle_s: float) -> None:
        self.idle_s = idle_s
        self.active = False
        self.airborne: dict[str, bool] = {}
        self.drones: set[str] = set()
        self._last_activity: float | None = None

    def observe(self, topic: str, type_name: str, msg: dict[str, Any], now: float) -> None:
        """Take in one graph message (only vehicle state messages matter)."""
        drone = drone_of(topic)
        if drone is None:
            return
        if type_name == "ardrone_autonomy/Navdata":
            up = msg.get("state") in AIRBORNE_STATES
        elif type_name.startswith("mavros_msgs/State"):
            up = bool(msg.get("armed"))
        else:
            return
        self.airborne[drone] = up
        if up:
            self.drones.add(drone)
            self._last_activity = now

    def touch(self, now: float) -> None:
        """An operator command happened (audited): a session starts or is kept open."""
        self._last_activity = now

    def poll(self, now: float) -> Change | None:
        """The change due at ``now``, if any (the caller opens or closes the recording)."""
        if any(self.airborne.values()):
            self._last_activity = now
        recent = self._last_activity is not None and now - self._last_activity < self.idle_s
        if not self.active and recent:
            self.active = True
            self.drones = {d for d, up in self.airborne.items() if up}
            return Change.START
        if self.active and not recent:
            self.active = False
            return Change.END
        return None
