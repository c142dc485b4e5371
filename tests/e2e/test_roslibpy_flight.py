"""roslibpy (PyPI, unchanged) flies the simulated AR.Drone through the whole server.

What a ROS user expects from ardrone_autonomy (topic names, message fields, std_msgs/Empty to
take off, Twist fractions to jog) checked against the simulator's ground truth over REST.
"""

from __future__ import annotations

import base64

import cv2
import numpy as np
import roslibpy

from tests.inbox import Inbox

from .conftest import TIMEOUT, Server

NAVDATA_FIELDS = {
    "header",
    "batteryPercent",
    "state",
    "rotX",
    "rotY",
    "rotZ",
    "altd",
    "vx",
    "vy",
    "vz",
    "ax",
    "ay",
    "az",
    "magX",
    "magY",
    "magZ",
    "pressure",
    "temp",
    "wind_speed",
    "wind_angle",
    "wind_comp_angle",
    "motor1",
    "motor2",
    "motor3",
    "motor4",
    "tags_count",
    "tags_type",
    "tags_xc",
    "tags_yc",
    "tags_width",
    "tags_height",
    "tags_orientation",
    "tags_distance",
    "tm",
}
# ardrone_autonomy's Navdata.state (major control state)
LANDED, FLYING, HOVERING, TAKEOFF, LANDING = 2, 3, 4, 6, 8


def test_navdata_has_ardrone_autonomy_fields(landed: Server, ros: roslibpy.Ros) -> None:
    inbox = Inbox()
    topic = roslibpy.Topic(ros, "/ardrone/navdata", "ardrone_autonomy/Navdata")
    topic.subscribe(inbox)
    try:
        msgs = inbox.wait(10)
    finally:
        topic.unsubscribe()
    msg = msgs[-1]
    assert set(msg) >= NAVDATA_FIELDS, NAVDATA_FIELDS - set(msg)
    assert msg["state"] == LANDED
    assert 90.0 <= msg["batteryPercent"] <= 100.0
    assert msg["altd"] == 0
    assert isinstance(msg["rotZ"], float)
    assert {"stamp", "frame_id"} <= set(msg["header"])
    # timestamps advance (tm in microseconds)
    assert msgs[-1]["tm"] > msgs[0]["tm"]


def test_compressed_image_is_a_640x360_jpeg(server: Server, ros: roslibpy.Ros) -> None:
    inbox = Inbox()
    topic = roslibpy.Topic(ros, "/ardrone/image_raw/compressed", "sensor_msgs/CompressedImage")
    topic.subscribe(inbox)
    try:
        msg = inbox.wait(2)[-1]
    finally:
        topic.unsubscribe()
    assert msg["format"] == "jpeg"
    raw = base64.b64decode(msg["data"])
    assert raw[:2] == b"\xff\xd8"
    img = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None
    assert img.shape == (360, 640, 3)
    assert float(img.std()) > 5.0  # a rendered room, not a blank frame


def test_rosapi_and_interpret_services(server: Server, ros: roslibpy.Ros) -> None:
    topics = roslibpy.Service(ros, "/rosapi/topics", "rosapi/Topics").call(
        roslibpy.ServiceRequest(), timeout=TIMEOUT
    )
    names = set(topics["topics"])
    expected = {
        "/ardrone/navdata",
        "/ardrone/image_raw/compressed",
        "/uav/pose",
        "/uav/markers",
        "/uav/task",
        "/console/reply",
        "/console/state",
    }
    assert expected <= names, expected - names
    types = dict(zip(topics["topics"], topics["types"], strict=True))
    assert types["/ardrone/navdata"] == "ardrone_autonomy/Navdata"
    assert types["/ardrone/image_raw/compressed"] == "sensor_msgs/CompressedImage"

    services = roslibpy.Service(ros, "/rosapi/services", "rosapi/Services").call(
        roslibpy.ServiceRequest(), timeout=TIMEOUT
    )
    assert {"/console/interpret", "/rosapi/topics"} <= set(services["services"])

    topic_type = roslibpy.Service(ros, "/rosapi/topic_type", "rosapi/TopicType").call(
        roslibpy.ServiceRequest({"topic": "/uav/pose"}), timeout=TIMEOUT
    )
    assert topic_type["type"] == "geometry_msgs/PoseStamped"

    interp = roslibpy.Service(ros, "/console/interpret", "uav_console/Interpret").call(
        roslibpy.ServiceRequest({"text": "take off and then go to marker 3"}), timeout=TIMEOUT
    )
    assert interp["commands"] == [{"action": "takeoff"}, {"action": "goto", "marker": 3}]

    state = Inbox()
    latched = roslibpy.Topic(ros, "/console/state", "uav_console/DialogState")
    latched.subscribe(state)
    try:
        first = state.wait(1)[0]
    finally:
        latched.unsubscribe()
    assert first["state"]


def test_takeoff_and_land_topics(landed: Server, ros: roslibpy.Ros) -> None:
    """std_msgs/Empty on /ardrone/takeoff and /ardrone/land, as with ardrone_autonomy."""
    srv = landed
    start = srv.truth()
    roslibpy.Topic(ros, "/ardrone/takeoff", "std_msgs/Empty").publish(roslibpy.Message({}))
    up = srv.wait_truth(lambda t: t["flying"] and t["z"] > 0.6, 15.0, "climbs after takeoff")
    assert abs(up["x"] - start["x"]) < 0.5 and abs(up["y"] - start["y"]) < 0.5

    nav = Inbox()
    navtopic = roslibpy.Topic(ros, "/ardrone/navdata", "ardrone_autonomy/Navdata")
    navtopic.subscribe(nav)
    try:
        items = nav.wait_until(
            lambda ms: bool(ms) and ms[-1]["altd"] > 500, TIMEOUT, "altd above 500 mm"
        )
    finally:
        navtopic.unsubscribe()
    assert items[-1]["state"] in {FLYING, HOVERING, TAKEOFF}

    roslibpy.Topic(ros, "/ardrone/land", "std_msgs/Empty").publish(roslibpy.Message({}))
    srv.wait_truth(lambda t: not t["flying"] and t["z"] < 0.05, 15.0, "lands after /ardrone/land")
