"""``MavrosNode`` in lockstep: MAVROS names and types on the graph, the jog pad's ``/cmd_vel``
streamed as velocities, and the silent operator's watchdog putting the autopilot into hold."""

from __future__ import annotations

import math
from typing import Any

import pytest

from drone.mavlink.lockstep import MavlinkLockstepRig
from drone.sim.world import load_world
from server.graph import Graph
from server.msgs import MESSAGES
from server.nodes.mavros_node import MAVROS_TOPICS, MavrosNode
from server.tasks.manager import TaskManager


@pytest.fixture(scope="module")
def world() -> Any:
    return load_world("outdoor")


def _node(
    world: Any, prefix: str = ""
) -> tuple[MavlinkLockstepRig, Graph, MavrosNode, dict[str, list[Any]]]:
    rig = MavlinkLockstepRig(world)
    g = Graph()
    tm = TaskManager(rig.vehicle, world, rig.clock)
    clock = rig.clock.now
    node = MavrosNode(g, rig.vehicle, tm, "uav1", prefix, clock=clock, stamp=clock)
    rig.add_stepper(lambda now, dt: node.step(now))
    got: dict[str, list[Any]] = {}
    for topic, _ in (*MAVROS_TOPICS.values(), ("/uav/pose", ""), ("/uav/task", "")):
        got[topic] = []
        g.subscribe(f"{prefix}{topic}", got[topic].append)
    assert rig.wait_link()
    rig.run(1.0)
    return rig, g, node, got


def test_mavros_topics_names_types_and_frames(world: Any) -> None:
    rig, g, _, got = _node(world, prefix="/uav3")
    for topic, type_ in MAVROS_TOPICS.values():
        assert f"/uav3{topic}" in g.topics()
        assert type_ in MESSAGES  # rosapi can describe it
    g.publish("/uav3/ardrone/takeoff", {})
    rig.run(8.0)
    state = got["/mavros/state"][-1]
    assert state["connected"] and state["armed"] and state["mode"] == "AUTO.LOITER"
    assert got["/mavros/extended_state"][-1]["landed_state"] == 2  # IN_AIR
    fix = got["/mavros/global_position/global"][-1]
    assert fix["latitude"] == pytest.approx(36.367164, abs=1e-5) and fix["status"]["status"] == 0
    assert got["/mavros/global_position/rel_alt"][-1]["data"] == pytest.approx(2.5, abs=0.15)
    local = got["/mavros/local_position/pose"][-1]["pose"]["position"]
    assert local["z"] == pytest.approx(2.5, abs=0.15)  # ENU, as MAVROS converts it
    assert 0.9 < got["/mavros/battery"][-1]["percentage"] <= 1.0
    assert got["/mavros/home_position/home"][-1]["geo"]["altitude"] == pytest.approx(60.0)
    assert "Takeoff detected" in [m["text"] for m in got["/mavros/statustext/recv"]]
    pose = got["/uav/pose"][-1]["pose"]
    assert pose["position"]["z"] == pytest.approx(2.5, abs=0.15)
    assert 2 * math.atan2(pose["orientation"]["z"], pose["orientation"]["w"]) == pytest.approx(
        math.pi / 2, abs=0.05
    )  # facing north, as the world's start
    assert 9 <= len(got["/mavros/global_position/global"]) / 9.0 <= 11  # 10 Hz


def test_cmd_vel_jog_and_the_silent_operator_watchdog(world: Any) -> None:
    rig, g, node, _ = _node(world)
    g.publish("/ardrone/takeoff", {})
    rig.run(8.0)
    g.publish("/cmd_vel", {"linear": {"x": 0.5, "y": 0.0, "z": 0.0}, "angular": {"z": 0.0}})
    rig.run(0.8)
    ap = rig.autopilot
    assert ap.mode == "OFFBOARD" and ap.physics.body.vy > 0.5
    assert rig.vehicle.protocol.streaming == "vel"
    rig.run(0.6)  # 1.4 s without /cmd_vel or a heartbeat from the operator
    assert node.watchdog_hovers == 1
    rig.run(2.0)
    assert ap.mode == "AUTO.LOITER" and rig.vehicle.protocol.streaming is None
    assert math.hypot(ap.physics.body.vx, ap.physics.body.vy) < 0.2
    g.publish("/cmd_vel", {"linear": {"x": "fast"}})  # bad message: logged, ignored
    g.publish("/ardrone/land", {})
    rig.run(8.0)
    assert not ap.armed and ap.physics.body.z == 0.0
