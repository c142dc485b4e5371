"""``MavrosNode``: a MAVLink drone on the graph under the names and types MAVROS uses.

Publishes (a fleet prefixes ``/NAME``, e.g. ``/uav2/mavros/state``), converted as MAVROS does
(mavlink/mavros ``sys_status.cpp``, ``global_position.cpp``, ``local_position.cpp``; NED → ENU):

- ``/mavros/state`` (mavros_msgs/State) at 1 Hz and on change: connected, armed, guided, mode
  (the autopilot's mode name, e.g. ``AUTO.LOITER``), system_status;
- ``/mavros/extended_state`` (mavros_msgs/ExtendedState): landed state;
- ``/mavros/global_position/global`` (sensor_msgs/NavSatFix), ``…/rel_alt`` and
  ``…/compass_hdg`` (std_msgs/Float64);
- ``/mavros/local_position/pose`` (geometry_msgs/PoseStamped, ENU, frame ``map``) and
  ``…/velocity_local`` (geometry_msgs/TwistStamped);
- ``/mavros/battery`` (sensor_msgs/BatteryState, percentage 0–1);
- ``/mavros/home_position/home`` (mavros_msgs/HomePosition);
- ``/mavros/statustext/recv`` (mavros_msgs/StatusText) for each STATUSTEXT;
- the console's own ``/uav/pose`` (the map-frame position, as the AR.Drone's EKF estimate) and
  ``/uav/task`` (through :class:`~server.nodes.vehicle_node.VehicleNode`).

Notices of the vehicle (denials with reasons, failsafes, link loss) go to ``/console/reply``
(level warn/alert), so the console shows and speaks them as it does ANS alarms.

Subscribes to ``/cmd_vel``, ``/ardrone/takeoff``, ``/ardrone/land``, ``/ardrone/reset`` like
the AR.Drone node (the console's buttons and jog pad drive both the same way).
"""

from __future__ import annotations

import math
from typing import Any

from drone.mavlink.gcs.events import MavlinkTelemetry
from drone.mavlink.geo import yaw_ned_to_enu
from server.msgs import header
from server.nodes.vehicle_node import EMPTY, POSE, TASK, TWIST, VehicleNode

REPLY = "/console/reply"
STATE_PERIOD_S = 1.0
FAST_PERIOD_S = 0.1  # 10 Hz for position topics, as the streams the driver asks for
MAVROS_TOPICS = {
    "state": ("/mavros/state", "mavros_msgs/State"),
    "extended": ("/mavros/extended_state", "mavros_msgs/ExtendedState"),
    "global": ("/mavros/global_position/global", "sensor_msgs/NavSatFix"),
    "rel_alt": ("/mavros/global_position/rel_alt", "std_msgs/Float64"),
    "hdg": ("/mavros/global_position/compass_hdg", "std_msgs/Float64"),
    "local": ("/mavros/local_position/pose", "geometry_msgs/PoseStamped"),
    "velocity": ("/mavros/local_position/velocity_local", "geometry_msgs/TwistStamped"),
    "battery": ("/mavros/battery", "sensor_msgs/BatteryState"),
    "home": ("/mavros/home_position/home", "mavros_msgs/HomePosition"),
    "statustext": ("/mavros/statustext/recv", "mavros_msgs/StatusText"),
}
MAVROS_LATCHED = ("state", "home")  # latched on the graph: a late subscriber gets the last
_LANDED = {"UNDEFINED": 0, "ON_GROUND": 1, "IN_AIR": 2, "TAKEOFF": 3, "LANDING": 4}


def _quat(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def _finite(v: float, default: float = 0.0) -> float:
    return v if math.isfinite(v) else default


class MavrosNode(VehicleNode):
    """See the module docstring. Same arguments as ``VehicleNode`` (vehicle: a MavlinkVehicle)."""

    def _advertise(self) -> None:
        g, o = self.graph, self.owner
        self.topic.update({k: self._name(v[0]) for k, v in MAVROS_TOPICS.items()})
        for key, (_, type_) in MAVROS_TOPICS.items():
            g.advertise(self.topic[key], type_, latch=key in MAVROS_LATCHED, owner=o)
        g.advertise(self.topic["pose"], POSE, owner=o)
        g.advertise(self.topic["task"], TASK, latch=True, owner=o)
        g.advertise(REPLY, "uav_console/Reply", owner=o)  # the vehicle's notices (with the dialog)
        self._subs = [
            g.subscribe(self.topic["cmd_vel"], self._on_cmd_vel, type=TWIST, owner=o),
            g.subscribe(self.topic["takeoff"], self._on_takeoff, type=EMPTY, owner=o),
            g.subscribe(self.topic["land"], self._on_land, type=EMPTY, owner=o),
            g.subscribe(self.topic["reset"], self._on_reset, type=EMPTY, owner=o),
        ]
        self._state_key: tuple[Any, ...] | None = None
        self._next_state = -math.inf
        self._next_fast = -math.inf
        self._home_key: tuple[float, ...] | None = None
        self.replies_published = 0
        self.tasks.on_event(lambda _n: self._publish_task(force=True))
        self._publish_task(force=True)

    def close(self) -> None:
        self._closed = True
        for s in self._subs:
            s.close()
        self._subs = []
        for key in (*MAVROS_TOPICS, "pose", "task"):
            self.graph.unadvertise(self.topic[key], self.owner)
        self.graph.unadvertise(REPLY, self.owner)

    def encode_image(self) -> dict[str, Any] | None:
        return None  # no camera stream over MAVLink

    def step(self, now: float, *, images: bool = True) -> None:
        super().step(now, images=False)
        if self._closed:
            return
        self._publish_notices()
        self.publish_telemetry(self.vehicle.protocol.telemetry, now)

    def _publish_notices(self) -> None:
        for notice in self.vehicle.drain_notices():
            text = notice.text
            self.graph.publish(
                REPLY,
                {
                    "header": header("map", self.stamp()),
                    "text": text,
                    "level": notice.level,
                    "speak": notice.level != "info",
                    "utterance": "",
                    "commands": "",
                },
            )
            self.replies_published += 1
            if text.startswith(f"{self.vehicle.name}: "):
                # the vehicle's own STATUSTEXT: also on /mavros/statustext/recv
                severity = {"alert": 2, "warn": 4, "info": 6}.get(notice.level, 6)
                self.graph.publish(
                    self.topic["statustext"],
                    {
                        "header": header("", self.stamp()),
                        "severity": severity,
                        "text": text.split(": ", 1)[1],
                    },
                )

    def publish_telemetry(self, t: MavlinkTelemetry, now: float) -> None:
        """Publish what is due (state 1 Hz and on change, positions 10 Hz)."""
        g, stamp = self.graph, self.stamp()
        connected = self.vehicle.protocol.connected
        key = (connected, t.armed, t.mode, t.system_status, t.landed_state)
        if key != self._state_key or now >= self._next_state:
            self._state_key = key
            self._next_state = now + STATE_PERIOD_S
            g.publish(
                self.topic["state"],
                {
                    "header": header("", stamp),
                    "connected": connected,
                    "armed": t.armed,
                    "guided": t.mode.startswith("AUTO") or t.mode in ("OFFBOARD", "GUIDED"),
                    "manual_input": False,
                    "mode": t.mode,
                    "system_status": t.system_status,
                },
            )
            g.publish(
                self.topic["extended"],
                {
                    "header": header("", stamp),
                    "vtol_state": 0,
                    "landed_state": _LANDED.get(t.landed_state, 0),
                },
            )
            if math.isfinite(t.battery_pct):
                g.publish(
                    self.topic["battery"],
                    {
                        "header": header("", stamp),
                        "voltage": _finite(t.voltage_v, math.nan),
                        "temperature": math.nan,
                        "current": math.nan,
                        "charge": math.nan,
                        "capacity": math.nan,
                        "design_capacity": math.nan,
                        "percentage": t.battery_pct / 100.0,
                        "power_supply_status": 2,  # DISCHARGING
                        "power_supply_health": 0,
                        "power_supply_technology": 3,  # LIPO
                        "present": True,
                        "cell_voltage": [],
                        "cell_temperature": [],
                        "location": "",
                        "serial_number": "",
                    },
                )
            if t.home is not None and t.home != self._home_key:
                self._home_key = t.home
                g.publish(
                    self.topic["home"],
                    {
                        "header": header("map", stamp),
                        "geo": {
                            "latitude": t.home[0],
                            "longitude": t.home[1],
                            "altitude": t.home[2],
                        },
                        "position": {"x": 0.0, "y": 0.0, "z": 0.0},
                        "orientation": _quat(0.0),
                        "approach": {"x": 0.0, "y": 0.0, "z": 0.0},
                    },
                )
        if now < self._next_fast or math.isnan(t.lat_deg):
            return
        self._next_fast = now + FAST_PERIOD_S
        g.publish(
            self.topic["global"],
            {
                "header": header("base_link", stamp),
                "status": {"status": 0 if t.gps_fix >= 2 else -1, "service": 1},
                "latitude": t.lat_deg,
                "longitude": t.lon_deg,
                "altitude": t.alt_amsl_m,
                "position_covariance": [
                    _finite(t.eph_m, 1.0) ** 2,
                    0,
                    0,
                    0,
                    _finite(t.eph_m, 1.0) ** 2,
                    0,
                    0,
                    0,
                    4.0,
                ],
                "position_covariance_type": 2,  # DIAGONAL_KNOWN
            },
        )
        g.publish(self.topic["rel_alt"], {"data": t.rel_alt_m})
        g.publish(self.topic["hdg"], {"data": math.degrees(t.heading_rad) % 360.0})
        yaw = yaw_ned_to_enu(t.heading_rad)
        if t.local_ned is not None:
            n, e, d = t.local_ned
            g.publish(
                self.topic["local"],
                {
                    "header": header("map", stamp),
                    "pose": {"position": {"x": e, "y": n, "z": -d}, "orientation": _quat(yaw)},
                },
            )
        g.publish(
            self.topic["velocity"],
            {
                "header": header("map", stamp),
                "twist": {
                    "linear": {"x": t.ve, "y": t.vn, "z": -t.vd},
                    "angular": {"x": 0.0, "y": 0.0, "z": 0.0},
                },
            },
        )
        pos = self.vehicle.map_position()
        if pos is not None:
            g.publish(
                self.topic["pose"],
                {
                    "header": header("map", stamp),
                    "pose": {
                        "position": {"x": pos[0], "y": pos[1], "z": pos[2]},
                        "orientation": _quat(yaw),
                    },
                },
            )
