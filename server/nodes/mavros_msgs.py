"""MAVROS message types, in the field order of mavros_msgs and sensor_msgs (ROS 1 Noetic), so
rosapi ``message_details`` and MAVROS-minded tools (Foxglove layouts, web dashboards) see the
types they expect on ``/mavros/...`` (mavlink/mavros ``mavros_msgs/msg/*.msg``)."""

from __future__ import annotations

Field = tuple[str, str]

MAVROS_MESSAGES: dict[str, tuple[Field, ...]] = {
    "mavros_msgs/State": (
        ("header", "std_msgs/Header"),
        ("connected", "bool"),
        ("armed", "bool"),
        ("guided", "bool"),
        ("manual_input", "bool"),
        ("mode", "string"),
        ("system_status", "uint8"),
    ),
    "mavros_msgs/ExtendedState": (
        ("header", "std_msgs/Header"),
        ("vtol_state", "uint8"),
        ("landed_state", "uint8"),
    ),
    "mavros_msgs/StatusText": (
        ("header", "std_msgs/Header"),
        ("severity", "uint8"),
        ("text", "string"),
    ),
    "mavros_msgs/HomePosition": (
        ("header", "std_msgs/Header"),
        ("geo", "geographic_msgs/GeoPoint"),
        ("position", "geometry_msgs/Point"),
        ("orientation", "geometry_msgs/Quaternion"),
        ("approach", "geometry_msgs/Vector3"),
    ),
    "geographic_msgs/GeoPoint": (
        ("latitude", "float64"),
        ("longitude", "float64"),
        ("altitude", "float64"),
    ),
    "sensor_msgs/NavSatStatus": (("status", "int8"), ("service", "uint16")),
    "sensor_msgs/NavSatFix": (
        ("header", "std_msgs/Header"),
        ("status", "sensor_msgs/NavSatStatus"),
        ("latitude", "float64"),
        ("longitude", "float64"),
        ("altitude", "float64"),
        ("position_covariance", "float64[]"),
        ("position_covariance_type", "uint8"),
    ),
    "sensor_msgs/BatteryState": (
        ("header", "std_msgs/Header"),
        ("voltage", "float32"),
        ("temperature", "float32"),
        ("current", "float32"),
        ("charge", "float32"),
        ("capacity", "float32"),
        ("design_capacity", "float32"),
        ("percentage", "float32"),
        ("power_supply_status", "uint8"),
        ("power_supply_health", "uint8"),
        ("power_supply_technology", "uint8"),
        ("present", "bool"),
        ("cell_voltage", "float32[]"),
        ("cell_temperature", "float32[]"),
        ("location", "string"),
        ("serial_number", "string"),
    ),
    "geometry_msgs/TwistStamped": (
        ("header", "std_msgs/Header"),
        ("twist", "geometry_msgs/Twist"),
    ),
}
