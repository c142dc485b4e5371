"""The vehicle's graph node in lockstep: ardrone_autonomy topics, /cmd_vel, operator watchdog."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pytest

from drone.sim.world import World, load_world
from server.graph import Graph
from server.nodes.vehicle_node import VehicleNode
from tests.autonomy.flight import Flight


@pytest.fixture(scope="module")
def world() -> World:
    return load_world("indoor")


TOPICS = ("ardrone/navdata", "ardrone/image_raw/compressed", "uav/pose", "uav/markers", "uav/task")
Got = dict[str, list[dict[str, Any]]]


def _node(
    world: World, prefix: str = "", camera: bool = True
) -> tuple[Flight, Graph, VehicleNode, Got]:
    f = Flight.make(world, seed=21, camera=camera, starts=[(2.0, 1.5, -math.pi / 2)])
    g = Graph()
    name = "uav2" if prefix else "uav1"
    clock = f.rig.clock.now
    node = VehicleNode(g, f.rig.vehicle, f.tm, name, prefix, clock=clock, stamp=clock)
    f.rig.add_stepper(lambda now, dt: node.step(now))
    got: Got = {}
    for topic in TOPICS:
        got[topic] = []
        g.subscribe(f"{prefix}/{topic}", got[topic].append)
    return f, g, node, got


def test_topics_carry_ardrone_autonomy_fields_and_the_estimate(world: World) -> None:
    f, g, node, got = _node(world)
    g.publish("/ardrone/takeoff", {})
    f.rig.run(4.0)
    assert f.rig.sim.truth.flying
    nav = got["ardrone/navdata"][-1]
    tr = f.rig.sim.truth
    assert nav["state"] in (3, 4)  # FLYING or HOVERING, the major ctrl_state
    assert nav["altd"] == pytest.approx(tr.z * 1000, abs=30)
    assert nav["rotZ"] == pytest.approx(math.degrees(tr.yaw_rad), abs=1.0)  # CCW degrees
    assert 0 < nav["batteryPercent"] <= 100
    assert 12 < len(got["ardrone/navdata"]) / 4.0 < 18  # demo navdata at 15 Hz
    pose = got["uav/pose"][-1]
    assert pose["header"]["frame_id"] == "map"
    assert pose["pose"]["position"]["x"] == pytest.approx(tr.x, abs=0.1)
    q = pose["pose"]["orientation"]
    assert 2 * math.atan2(q["z"], q["w"]) == pytest.approx(tr.yaw_rad, abs=0.05)
    marks = [m for msg in got["uav/markers"] for m in msg["markers"]]
    assert {m["id"] for m in marks} & {0, 1}  # facing the south wall
    img = got["ardrone/image_raw/compressed"][-1]
    assert img["format"] == "jpeg"
    assert isinstance(img["data"], bytes)  # the JPEG itself: base64 is made for a client's JSON
    frame = cv2.imdecode(np.frombuffer(img["data"], np.uint8), cv2.IMREAD_COLOR)
    assert frame.shape == (360, 640, 3)
    assert 40 <= node.images_published <= 61  # ≤ 15 fps over 4 s
    task = g.latched("/uav/task")
    assert task is not None and task["drone"] == "uav1"


def test_cmd_vel_jogs_cancels_the_task_and_the_silent_operator_gets_a_hover(world: World) -> None:
    f, g, node, got = _node(world, camera=False)
    f.submit({"action": "takeoff"})
    assert f.run_until_idle(12.0)
    f.submit({"action": "move", "direction": "forward", "distance": 0.5})
    f.rig.run(0.3)
    assert f.tm.status.name == "move"
    g.publish("/cmd_vel", {"linear": {"x": 0.3, "y": 0.0, "z": 0.0}, "angular": {"z": 0.0}})
    assert f.tm.current is None
    assert got["uav/task"][-1]["state"] == "idle"
    assert f.rig.vehicle.snapshot().mode == "manual"
    f.rig.run(0.5)
    node.operator_heartbeat()  # still there
    f.rig.run(0.8)
    assert f.rig.vehicle.snapshot().mode == "manual"
    f.rig.run(0.4)  # 1.2 s of silence
    assert f.rig.vehicle.snapshot().mode == "idle" and node.watchdog_hovers == 1
    g.publish("/cmd_vel", {"linear": {"x": "fast"}})  # bad message: logged, ignored
    assert f.rig.vehicle.snapshot().mode == "idle"
    g.publish("/ardrone/land", {})
    f.rig.run(5.0)
    assert not f.rig.sim.truth.flying


def test_a_fleet_prefixes_every_topic(world: World) -> None:
    f, g, node, got = _node(world, prefix="/uav2", camera=False)
    assert "/uav2/ardrone/navdata" in g.topics() and "/ardrone/navdata" not in g.topics()
    g.publish("/uav2/ardrone/takeoff", {})
    f.rig.run(3.0)
    assert f.rig.sim.truth.flying
    assert got["ardrone/navdata"]
    assert g.latched("/uav2/uav/task")["drone"] == "uav2"
    node.close()
    assert g.publishers("/uav2/ardrone/navdata") == []
    n = len(got["ardrone/navdata"])
    f.rig.run(0.5)
    assert len(got["ardrone/navdata"]) == n  # closed: publishes nothing more
