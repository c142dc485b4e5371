"""The key space (``docs/bus.md``): ``uavc/<fleet>/<drone>/<topic>`` and the central's keys.

| key | what |
|---|---|
| ``uavc/<fleet>/<drone>/telemetry`` | :class:`~drone.bus.payloads.Telemetry`, JSON, ≥ 5 Hz |
| ``uavc/<fleet>/<drone>/alive`` | liveliness token of the vehicle process |
| ``uavc/<fleet>/<drone>/cmd`` | commands: queries answered by the vehicle (:mod:`.commands`) |
| ``uavc/<fleet>/<drone>/status`` | :class:`~drone.bus.payloads.Status`, JSON, 1 Hz |
| ``uavc/<fleet>/<drone>/camera`` | JPEG frames, dropped rather than queued |
| ``uavc/<fleet>/<drone>/graph/<topic>`` | its own graph topics, JSON (what a console shows) |
| ``uavc/<fleet>/console/<name>/alive`` | liveliness of each console on the bus (one token) |
| ``uavc/<fleet>/console/<name>/heartbeat`` | ``{"t": Unix s}`` at 10 Hz from each console |
| ``uavc/<fleet>/central/alive`` | liveliness of the console holding the central role |
| ``uavc/<fleet>/central/missions`` | the JSON of ``GET /api/v1/patrol`` |
"""

from __future__ import annotations

import re

from drone.bus.errors import KeySegmentError

ROOT = "uavc"
DEFAULT_FLEET = "default"
CENTRAL = "central"  # not a drone name: the central role's own keys
CONSOLE = "console"  # not a drone name: every console's liveliness
SEGMENT = re.compile(r"[A-Za-z0-9_-]{1,64}")


def segment(name: str) -> str:
    """``name`` as one key segment.

    Raises:
        KeySegmentError: empty, too long, or holding a character with a meaning in key
            expressions (``/``, ``*``, ``$``, ``?``, ``#``) or outside ``[A-Za-z0-9_-]``.
    """
    if not SEGMENT.fullmatch(name):
        raise KeySegmentError(f"{name!r} cannot name a fleet or drone on the bus ([A-Za-z0-9_-])")
    return name


def drone_key(fleet: str, drone: str, topic: str) -> str:
    if drone in (CENTRAL, CONSOLE):
        raise KeySegmentError(f"{drone!r} is a key of the consoles', not a drone's name")
    return f"{ROOT}/{segment(fleet)}/{segment(drone)}/{topic}"


def telemetry(fleet: str, drone: str) -> str:
    return drone_key(fleet, drone, "telemetry")


def alive(fleet: str, drone: str) -> str:
    return drone_key(fleet, drone, "alive")


def command(fleet: str, drone: str) -> str:
    return drone_key(fleet, drone, "cmd")


def status(fleet: str, drone: str) -> str:
    return drone_key(fleet, drone, "status")


def camera(fleet: str, drone: str) -> str:
    return drone_key(fleet, drone, "camera")


def graph(fleet: str, drone: str, topic: str) -> str:
    """A vehicle's graph topic on the bus: ``/uav7/ardrone/navdata`` →
    ``uavc/<fleet>/uav7/graph/uav7/ardrone/navdata``."""
    return f"{drone_key(fleet, drone, 'graph')}/{topic.strip('/')}"


def all_graph(fleet: str, drone: str) -> str:
    return f"{drone_key(fleet, drone, 'graph')}/**"


def topic_of_graph(key: str) -> str | None:
    """The graph topic a ``…/<drone>/graph/<topic>`` key carries (None for other keys)."""
    parts = key.split("/")
    if len(parts) < 5 or parts[0] != ROOT or parts[3] != "graph":
        return None
    return "/" + "/".join(parts[4:])


def all_status(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/*/status"


def all_camera(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/*/camera"


def all_telemetry(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/*/telemetry"


def all_alive(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/*/alive"


def console_alive(fleet: str, console: str) -> str:
    """Liveliness of one console on the bus (any role), its only presence token: a vehicle
    hears its consoles by it, and the consoles elect the central among those it names."""
    return f"{ROOT}/{segment(fleet)}/{CONSOLE}/{segment(console)}/alive"


def all_consoles_alive(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/{CONSOLE}/*/alive"


def console_of(key: str) -> str | None:
    """The console a ``uavc/<fleet>/console/<name>/…`` key names (None for other keys)."""
    parts = key.split("/")
    if len(parts) < 5 or parts[0] != ROOT or parts[2] != CONSOLE:
        return None
    return parts[3]


def console_heartbeat(fleet: str, console: str) -> str:
    """One console's heartbeat (10 Hz, its clock): a vehicle hovers when none comes."""
    return f"{ROOT}/{segment(fleet)}/{CONSOLE}/{segment(console)}/heartbeat"


def all_console_heartbeats(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/{CONSOLE}/*/heartbeat"


def central_alive(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/{CENTRAL}/alive"


def central_missions(fleet: str) -> str:
    return f"{ROOT}/{segment(fleet)}/{CENTRAL}/missions"


def drone_of(key: str) -> str | None:
    """The drone a ``uavc/<fleet>/<drone>/…`` key names (None for other keys)."""
    parts = key.split("/")
    if len(parts) < 4 or parts[0] != ROOT or parts[2] in (CENTRAL, CONSOLE):
        return None
    return parts[2]
