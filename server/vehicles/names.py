"""Names on the graph that a vehicle process adds to the drone's ordinary topics (DESIGN §4).

A vehicle process shows its drone on its consoles' graphs through the bus (docs/bus.md: its
graph topics on ``uavc/<fleet>/<drone>/graph/…``, its control ops as ``cmd`` queries): the same
topics an in-process drone has (``/ardrone/navdata``, ``/uav/pose`` …, prefixed in a fleet)
plus these:

- ``/NAME/vehicle/info`` (std_msgs/String, latched; ``data`` = JSON ``{name, prefix,
  simulated, door_url, door_tickets, pid}``): announces the vehicle; the central registry
  makes a drone of it;
- ``/NAME/vehicle/telemetry`` (std_msgs/String, 10 Hz; ``data`` = the JSON of
  ``GET /drones/{id}``, plus ``truth`` for a simulated drone);
- ``/NAME/vehicle/control`` (service ``uav_console/VehicleControl``; args ``{op, ...}``): ``op``
  is ``direct`` (``action``), ``fault`` (``kind``, ``duration_s``, ``battery_pct``,
  ``wind_mps``), ``telemetry``, ``truth``, or a task op that the console's dialog sends what it
  understood with: ``submit`` (``commands``), ``preempt`` (``command``, ``by``), ``cancel``
  (typed commands, drone/commands.py; :mod:`server.vehicles.task_ops`);
- ``/NAME/vehicle/task_event`` (std_msgs/String; ``data`` = JSON ``{kind, text, task, state,
  queued}``): the task executor's notices, which the console's dialog follows and says;
- ``/NAME/vehicle/alarm`` (std_msgs/String): the supervisor's alarms, which the console's dialog
  says; ``/NAME/vehicle/reply`` (uav_console/Reply): what the vehicle's nodes say themselves (a
  command past its deadline, a MAVLink autopilot's denial), checked and re-published by the
  console (:mod:`server.vehicles.relay`). The vehicle runs no dialog: the console is the only
  publisher of ``/console/reply``, ``PREFIX/console/state`` and ``PREFIX/console/interpret``.

A console's heartbeat (its clock, and the id of the flight recording being written, for the
vehicle's audit rows) is on the bus: ``uavc/<fleet>/console/<name>/heartbeat``.
"""

from __future__ import annotations

from pathlib import Path

STRING = "std_msgs/String"
CONTROL_TYPE = "uav_console/VehicleControl"
# The console's beat on its graph (``{n, t}``: a counter and its Unix time, 10 Hz), by which a
# page or rosbridge client tells a stalled console (web/static/js/app.js).
HEARTBEAT = "/vehicles/heartbeat"
HEARTBEAT_PERIOD_S = 0.1  # the console's beat, on its graph and on the bus
# A vehicle process's exit status when it cannot start here (errors.CannotStart): its
# supervisor does not start it again, since it would fail the same way.
EXIT_CANNOT_START = 3


def info_topic(name: str) -> str:
    return f"/{name}/vehicle/info"


def telemetry_topic(name: str) -> str:
    return f"/{name}/vehicle/telemetry"


def alarm_topic(name: str) -> str:
    """The supervisor's alarms (``std_msgs/String``, JSON of ``drone.supervisor.Alarm``)."""
    return f"/{name}/vehicle/alarm"


def control_service(name: str) -> str:
    return f"/{name}/vehicle/control"


def reply_topic(name: str) -> str:
    """What the vehicle's own parts say (uav_console/Reply; :mod:`server.vehicles.relay`)."""
    return f"/{name}/vehicle/reply"


def task_event_topic(name: str) -> str:
    """The task executor's notices (``std_msgs/String``, JSON: :mod:`server.vehicles.task_ops`)."""
    return f"/{name}/vehicle/task_event"


def drone_order(name: str) -> tuple[str, int, str]:
    """Sort key that lists drones as people count them: uav2 before uav10, whatever order
    their vehicle processes happened to join in."""
    stem = name.rstrip("0123456789")
    digits = name[len(stem) :]
    return (stem, int(digits) if digits else -1, name)


def pid_dir(data_dir: Path, port: int) -> Path:
    """Where a console's vehicle processes leave their pid (``NAME.pid``): one directory per
    console port, so two consoles sharing a data directory never take each other's vehicles
    for their own (a vehicle writes its pid under its console's port, one of the settings
    ``serve`` passes the vehicles it spawns)."""
    return data_dir / "vehicles" / str(port)
