"""A short flight written by the real recorder from the messages a drone stack publishes.

Used where a test needs a recording but not a simulator run (the browser replay test): the
topics, types and rates are those of ``server.nodes.vehicle_node`` and the dialog manager, the
camera frames are real JPEGs, the drone takes off, flies a 1 m square and lands.
"""

from __future__ import annotations

import base64
import math
from pathlib import Path

import cv2
import numpy as np

from server import msgs
from server.graph import Graph
from server.recorder.recorder import Recorder, RecorderConfig

IMAGE = "sensor_msgs/CompressedImage"


def jpeg(n: int) -> str:
    img = np.full((360, 640, 3), 90, np.uint8)
    cv2.putText(img, f"frame {n}", (40, 180), cv2.FONT_HERSHEY_SIMPLEX, 2, (255, 255, 255), 3)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 70])
    assert ok
    return base64.b64encode(buf.tobytes()).decode("ascii")


def write_flight(directory: Path, seconds: float = 12.0, rate_hz: float = 10.0) -> Path:
    """Record a synthetic flight into ``directory``; returns the finished file."""
    graph = Graph()
    clock = [1000.0]
    rec = Recorder(
        graph,
        RecorderConfig(directory, idle_s=1.0, world="indoor"),
        clock=lambda: clock[0],
        stamp_ns=lambda: int(clock[0] * 1e9),
    )
    rec.start(background=False)
    reply = {"header": msgs.header(), "level": "info", "speak": False, "commands": "[]"}
    said = {"drone": "uav1", "asked_by": ""}
    graph.publish(  # through REST: the door's own record of it
        "/console/utterance",
        {**said, "text": "take off", "confidence": 1.0, "source": "rest", "answered": True},
        type="uav_console/Utterance",
    )
    graph.publish(
        "/console/reply",
        {**reply, "text": "Taking off.", "utterance": "take off"},
        type="uav_console/Reply",
    )
    steps = int(seconds * rate_hz)
    for i in range(steps):
        t = i / rate_hz
        state = 2 if i in (0, steps - 1) else 6 if t < 1 else 8 if t > seconds - 1.5 else 3
        side = (t % 8.0) / 2.0
        x, y = [(side, 0.0), (1.0, side - 1), (3 - side, 1.0), (0.0, 4 - side)][int(side) % 4]
        nav = msgs.default_message("ardrone_autonomy/Navdata")
        nav.update(header=msgs.header("ardrone_base_link"), state=state, altd=1000)
        nav["batteryPercent"] = 90.0 - t
        graph.publish("/ardrone/navdata", nav, type="ardrone_autonomy/Navdata")
        pose = {
            "header": msgs.header("map"),
            "pose": {
                "position": {"x": 2.0 + x, "y": 2.0 + y, "z": 1.0},
                "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(t / 4), "w": math.cos(t / 4)},
            },
        }
        graph.publish("/uav/pose", pose, type="geometry_msgs/PoseStamped")
        if i % 2 == 0:
            image = {"header": msgs.header("cam"), "format": "jpeg", "data": jpeg(i)}
            graph.publish("/ardrone/image_raw/compressed", image, type=IMAGE)
        if i == int(10 * rate_hz):  # spoken on the page 10 s in (the replay test's first
            # look, before it, sees "Taking off." as the latest reply)
            asked = {"text": "how high are you", "confidence": 0.87, "source": "speech"}
            graph.publish("/console/utterance", {**said, **asked}, type="uav_console/Utterance")
            graph.publish(
                "/console/reply",
                {**reply, "text": "I am at 1.0 meters.", "utterance": asked["text"]},
                type="uav_console/Reply",
            )
        clock[0] += 1.0 / rate_hz
        rec.step()
    graph.publish(  # from a rosbridge client
        "/console/utterance",
        {**said, "text": "land", "confidence": 1.0, "source": "rosbridge"},
        type="uav_console/Utterance",
    )
    graph.publish(
        "/console/reply",
        {**reply, "text": "Landed.", "utterance": "land"},
        type="uav_console/Reply",
    )
    clock[0] += 5.0
    rec.step()
    rec.stop()
    (row,) = rec.flights()
    return rec.index.path_for(row.id)
