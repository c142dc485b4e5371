"""Message and service type definitions of the graph, in ROS field order.

Each type is a tuple of ``(field name, field type)``; a field type is a primitive (``bool``,
``int32``, ``uint32``, ``float32``, ``float64``, ``string``, ``time`` …), another type name,
or either followed by ``[]`` for a variable-length array. Used for rosapi ``message_details``,
for checking what clients publish, and for filling defaults (``header.stamp``).
"""

from __future__ import annotations

import math
import time
from typing import Any

from server.nodes.mavros_msgs import MAVROS_MESSAGES

Field = tuple[str, str]

PRIMITIVES: dict[str, Any] = {
    "bool": False,
    "byte": 0,
    "char": 0,
    "int8": 0,
    "uint8": 0,
    "int16": 0,
    "uint16": 0,
    "int32": 0,
    "uint32": 0,
    "int64": 0,
    "uint64": 0,
    "float32": 0.0,
    "float64": 0.0,
    "string": "",
}

MESSAGES: dict[str, tuple[Field, ...]] = {
    "builtin_interfaces/Time": (("sec", "int32"), ("nanosec", "uint32")),
    "std_msgs/Empty": (),
    "std_msgs/String": (("data", "string"),),
    "std_msgs/Bool": (("data", "bool"),),
    "std_msgs/Float32": (("data", "float32"),),
    "std_msgs/Float64": (("data", "float64"),),
    "std_msgs/Int32": (("data", "int32"),),
    "std_msgs/Header": (("stamp", "builtin_interfaces/Time"), ("frame_id", "string")),
    "geometry_msgs/Vector3": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/Point": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/Quaternion": (
        ("x", "float64"),
        ("y", "float64"),
        ("z", "float64"),
        ("w", "float64"),
    ),
    "geometry_msgs/Pose": (
        ("position", "geometry_msgs/Point"),
        ("orientation", "geometry_msgs/Quaternion"),
    ),
    "geometry_msgs/PoseStamped": (("header", "std_msgs/Header"), ("pose", "geometry_msgs/Pose")),
    "geometry_msgs/Twist": (
        ("linear", "geometry_msgs/Vector3"),
        ("angular", "geometry_msgs/Vector3"),
    ),
    "sensor_msgs/CompressedImage": (
        ("header", "std_msgs/Header"),
        ("format", "string"),
        ("data", "uint8[]"),
    ),
    # Field names as in ardrone_autonomy's Navdata.msg (AutonomyLab/ardrone_autonomy).
    "ardrone_autonomy/Navdata": (
        ("header", "std_msgs/Header"),
        ("batteryPercent", "float32"),
        ("state", "uint32"),
        ("magX", "int32"),
        ("magY", "int32"),
        ("magZ", "int32"),
        ("pressure", "int32"),
        ("temp", "int32"),
        ("wind_speed", "float32"),
        ("wind_angle", "float32"),
        ("wind_comp_angle", "float32"),
        ("rotX", "float32"),
        ("rotY", "float32"),
        ("rotZ", "float32"),
        ("altd", "int32"),
        ("vx", "float32"),
        ("vy", "float32"),
        ("vz", "float32"),
        ("ax", "float32"),
        ("ay", "float32"),
        ("az", "float32"),
        ("motor1", "uint8"),
        ("motor2", "uint8"),
        ("motor3", "uint8"),
        ("motor4", "uint8"),
        ("tags_count", "uint32"),
        ("tags_type", "uint32[]"),
        ("tags_xc", "uint32[]"),
        ("tags_yc", "uint32[]"),
        ("tags_width", "uint32[]"),
        ("tags_height", "uint32[]"),
        ("tags_orientation", "float32[]"),
        ("tags_distance", "float32[]"),
        ("tm", "float32"),
    ),
    # ardrone_autonomy's navdata_gps.msg and navdata_gps_channel.msg (AutonomyLab/
    # ardrone_autonomy): the AR.Drone's GPS navdata option (tag 27), field for field.
    "ardrone_autonomy/navdata_gps_channel": (("sat", "uint8"), ("c_n0", "uint8")),
    "ardrone_autonomy/navdata_gps": (
        ("header", "std_msgs/Header"),
        ("tag", "uint16"),
        ("size", "uint16"),
        ("latitude", "float64"),
        ("longitude", "float64"),
        ("elevation", "float64"),
        ("hdop", "float64"),
        ("data_available", "uint32"),
        ("zero_validated", "bool"),
        ("wpt_validated", "bool"),
        ("lat0", "float64"),
        ("long0", "float64"),
        ("lat_fused", "float64"),
        ("long_fused", "float64"),
        ("gps_state", "uint32"),
        ("X_traj", "float32"),
        ("X_ref", "float32"),
        ("Y_traj", "float32"),
        ("Y_ref", "float32"),
        ("theta_p", "float32"),
        ("phi_p", "float32"),
        ("theta_i", "float32"),
        ("phi_i", "float32"),
        ("theta_d", "float32"),
        ("phi_d", "float32"),
        ("vdop", "float64"),
        ("pdop", "float64"),
        ("speed", "float32"),
        ("lastFrameTimestamp", "uint32"),
        ("degree", "float32"),
        ("degree_magnetic", "float32"),
        ("ehpe", "float32"),
        ("ehve", "float32"),
        ("c_n0", "float32"),
        ("nbsat", "uint32"),
        ("channels", "ardrone_autonomy/navdata_gps_channel[12]"),
        ("is_gps_plugged", "bool"),
        ("ephemerisStatus", "uint32"),
        ("vx_traj", "float32"),
        ("vy_traj", "float32"),
        ("firmwareStatus", "uint32"),
    ),
    "uav_console/Marker": (
        ("id", "int32"),
        ("pose", "geometry_msgs/Pose"),
        ("distance", "float64"),
    ),
    "uav_console/MarkerArray": (
        ("header", "std_msgs/Header"),
        ("markers", "uav_console/Marker[]"),
    ),
    "uav_console/TaskStatus": (
        ("header", "std_msgs/Header"),
        ("drone", "string"),
        ("name", "string"),
        ("state", "string"),
        ("progress", "float64"),
        ("detail", "string"),
    ),
    "uav_console/Utterance": (
        ("text", "string"),
        ("confidence", "float64"),
        ("source", "string"),
        ("drone", "string"),
        # The drone whose "Did you say …?" the console has open while another drone is
        # selected: a bare yes or no goes to it (server/dialog/manager.py), else "".
        ("asked_by", "string"),
        # True on the copy a door that answers by itself (REST POST /command, POST /speech)
        # publishes so that every input is on the graph and in the recording: no dialog acts
        # on it (it has already had its answer).
        ("answered", "bool"),
    ),
    "uav_console/Reply": (
        ("header", "std_msgs/Header"),
        ("text", "string"),
        ("level", "string"),
        ("speak", "bool"),
        ("utterance", "string"),
        ("commands", "string"),
        ("drone", "string"),  # the drone that answers (fleets)
        ("alarm", "string"),  # the ANS monitor that raised it (battery, link, …), else ""
        ("expects", "string"),  # "confirm": a yes/no question ("Did you say …?"), else ""
    ),
    "uav_console/DialogState": (
        ("header", "std_msgs/Header"),
        ("drone", "string"),
        ("state", "string"),
        ("grammars", "string[]"),
    ),
    "uav_console/DroneStatus": (
        ("name", "string"),
        ("role", "string"),
        ("position", "geometry_msgs/Point"),
        ("yaw_deg", "float64"),
        ("latitude", "float64"),
        ("longitude", "float64"),
        ("battery", "float64"),
        ("state", "string"),
        ("mission", "string"),
        ("link", "bool"),
    ),
    "uav_console/FleetStatus": (
        ("header", "std_msgs/Header"),
        ("drones", "uav_console/DroneStatus[]"),
        ("events", "string[]"),
    ),
    # ros/ros_comm rosgraph_msgs/Log.msg; its level constants (DEBUG=1 … FATAL=16) are in
    # server.ros1.definitions. On /rosout, Foxglove tells ROS 1 from ROS 2 by this type.
    "rosgraph_msgs/Log": (
        ("header", "std_msgs/Header"),
        ("level", "byte"),
        ("name", "string"),
        ("msg", "string"),
        ("file", "string"),
        ("function", "string"),
        ("line", "uint32"),
        ("topics", "string[]"),
    ),
}


MESSAGES.update(MAVROS_MESSAGES)  # /mavros/... topics of MAVLink drones


def is_array(field_type: str) -> bool:
    return field_type.endswith("]")


def base_type(field_type: str) -> str:
    return field_type.split("[", 1)[0]


def array_length(field_type: str) -> int:
    """rosapi's ``fieldarraylen``: -1 for a scalar, 0 for a variable-length array, N for
    ``T[N]``."""
    if not is_array(field_type):
        return -1
    inner = field_type[len(base_type(field_type)) + 1 : -1]
    return int(inner) if inner else 0


def default_message(type_name: str) -> dict[str, Any]:
    """A message of ``type_name`` with every field at its ROS default (a fixed-size array
    holds its N defaults)."""
    out: dict[str, Any] = {}
    for name, ftype in MESSAGES.get(type_name, ()):
        if is_array(ftype):
            base = base_type(ftype)
            item = PRIMITIVES.get(base)
            n = array_length(ftype)
            out[name] = [item if base in PRIMITIVES else default_message(base) for _ in range(n)]
        elif ftype in PRIMITIVES:
            out[name] = PRIMITIVES[ftype]
        else:
            out[name] = default_message(ftype)
    return out


def stamp(now: float | None = None) -> dict[str, int]:
    """A ``builtin_interfaces/Time`` for ``now`` (seconds since the epoch; wall clock if None)."""
    t = time.time() if now is None else now
    sec = math.floor(t)
    return {"sec": int(sec), "nanosec": round((t - sec) * 1e9) % 1_000_000_000}


def header(frame_id: str = "map", now: float | None = None) -> dict[str, Any]:
    return {"stamp": stamp(now), "frame_id": frame_id}
