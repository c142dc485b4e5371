"""PENDING (not collected: the file name does not start with ``test_``). Rename to
``test_pending_flight.py`` once the integration bugs in the e2e REPORT are fixed:

1. the fleet's in-process LocalTaskManager flies every manually launched drone home
   (``server/fleet/ltm.py`` ``step``: ``silent = self.last_ctm is None or ...``);
2. the dialog manager stays LANDED after a take-off that bypassed it (``/ardrone/takeoff``,
   ``POST /drones/uav1/takeoff``) and then refuses a spoken "land" with
   "I am already on the ground.".
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import roslibpy

from tests.inbox import Inbox
from tests.support.polling import wait_for

from .conftest import TIMEOUT, Server

LANDED, FLYING, HOVERING, TAKEOFF, LANDING = 2, 3, 4, 6, 8


def _speed(t: dict[str, Any]) -> float:
    return float(np.hypot(t["vx"], t["vy"]))


def test_takeoff_jog_watchdog_and_spoken_land(landed: Server, ros: roslibpy.Ros) -> None:
    srv = landed
    start = srv.truth()

    # take off with std_msgs/Empty, as with ardrone_autonomy
    takeoff = roslibpy.Topic(ros, "/ardrone/takeoff", "std_msgs/Empty")
    takeoff.publish(roslibpy.Message({}))
    up = srv.wait_truth(lambda t: t["flying"] and t["z"] > 0.6, 15.0, "climbs after takeoff")
    assert abs(up["x"] - start["x"]) < 0.5 and abs(up["y"] - start["y"]) < 0.5
    srv.wait_truth(lambda t: t["ctrl_state"] == "HOVERING", 10.0, "hovering after takeoff")

    # navdata follows: state FLYING/HOVERING, altd in mm
    nav = Inbox()
    navtopic = roslibpy.Topic(ros, "/ardrone/navdata", "ardrone_autonomy/Navdata")
    navtopic.subscribe(nav)
    try:
        items = nav.wait_until(
            lambda ms: bool(ms) and ms[-1]["altd"] > 500, TIMEOUT, "altd above 500 mm"
        )
    finally:
        navtopic.unsubscribe()
    assert items[-1]["state"] in {FLYING, HOVERING}

    # jog forward: linear.x = 0.3 for about 1 s; yaw is 0 so body forward is map +x
    before = srv.truth()
    cmd_vel = roslibpy.Topic(ros, "/cmd_vel", "geometry_msgs/Twist")
    jog = {"linear": {"x": 0.3, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        cmd_vel.publish(roslibpy.Message(jog))
        time.sleep(0.05)  # a jog at 20 Hz for a second: the test's input
    last_publish = time.monotonic()
    moving = srv.truth()
    assert moving["vx"] > 0.3, moving
    assert abs(moving["vy"]) < 0.5 * moving["vx"], moving

    # stop publishing: the operator watchdog (1 s) hovers it and the velocity decays
    after = srv.wait_truth(lambda t: _speed(t) < 0.1, 5.0, "velocity decays after jog")
    assert time.monotonic() - last_publish < 4.0
    assert after["x"] - before["x"] > 0.2, (before, after)
    assert after["z"] > 0.4  # still flying
    drone = srv.drone()
    assert drone["mode"] == "idle", drone

    # a typed "land" on /console/utterance gets a reply and lands the drone
    replies = Inbox()
    reply_topic = roslibpy.Topic(ros, "/console/reply", "uav_console/Reply")
    reply_topic.subscribe(replies)
    utter = roslibpy.Topic(ros, "/console/utterance", "uav_console/Utterance")
    try:
        # roslibpy subscribes asynchronously: wait until our subscription is on the graph
        _wait_subscribed(ros, "/console/reply")
        utter.publish(
            roslibpy.Message({"text": "land", "confidence": 1.0, "source": "text", "drone": "uav1"})
        )
        reply = replies.wait(1, 10.0)[0]
    finally:
        reply_topic.unsubscribe()
    assert reply["text"]
    assert reply["level"] in {"info", "warn", "alert"}
    srv.wait_truth(lambda t: not t["flying"] and t["z"] < 0.05, 15.0, "lands after spoken land")


def _wait_subscribed(ros: roslibpy.Ros, topic: str) -> None:
    """Poll rosapi until the server lists a subscriber on ``topic`` (nothing to sleep on)."""
    svc = roslibpy.Service(ros, "/rosapi/subscribers", "rosapi/Subscribers")

    def subscribers() -> list[str]:
        reply = svc.call(roslibpy.ServiceRequest({"topic": topic}), timeout=TIMEOUT)
        return list(reply["subscribers"])

    wait_for(subscribers, lambda subs: len(subs) >= 1, 5.0, f"subscribers of {topic}")


def test_goto_marker_through_rest_command(landed: Server) -> None:
    """ "take off and go to marker N" via POST /api/v1/command, flown in real time."""
    srv = landed
    world = srv.http.get("/api/v1/world").json()
    start = srv.truth()
    markers = sorted(
        world["markers"],
        key=lambda m: np.hypot(m["position"]["x"] - start["x"], m["position"]["y"] - start["y"]),
    )
    target = markers[1]
    r = srv.http.post("/api/v1/command", json={"text": f"take off and go to marker {target['id']}"})
    body = r.json()
    assert body["accepted"], body
    assert body["commands"] == [{"action": "takeoff"}, {"action": "goto", "marker": target["id"]}]
    pos = target["position"]

    def near(t: dict[str, Any]) -> bool:
        return bool(np.hypot(t["x"] - pos["x"], t["y"] - pos["y"]) < 1.5 and t["flying"])

    t0 = time.monotonic()
    wait_for(srv.truth, near, 40.0, f"near marker {target['id']}")
    done = wait_for(srv.drone, lambda d: d["task"]["state"] == "idle", 10.0, "task done")
    assert done["localised"], done
    assert time.monotonic() - t0 < 40.0
