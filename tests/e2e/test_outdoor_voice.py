"""Waypoints by voice outdoors, in real time, through a real ``serve --world outdoor --fleet 2``
(each drone in its own vehicle process, its simulator behind the AR.Drone protocol).

The operator types what a new user would say ("drone 2, fly to waypoint 3") over REST; the
replies come back right ("uav2: Flying to waypoint 3.", then that it got there, never a marker
search), and the simulator's ground truth says the drone is at waypoint 3 while the other drone
stayed on the ground. Meanwhile Foxglove's own libraries (tests/node/foxglove_client.mjs) read
``/uav2/ardrone/navdata_gps`` through rosapi and cbor-raw, as the GPS of the drone flying.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path
from typing import Any

import pymap3d
import pytest
import roslibpy

from drone.sim.world import load_world
from tests.e2e.served import serve
from tests.recorder.test_foxglove import NODE_DIR, node_exe
from tests.support.loopback import fresh_address
from tests.support.polling import wait_for

TOKEN = "outdoor-voice-pilot"
WP3 = (15.0, 15.0, 2.5)  # worlds/outdoor.yaml wp3


def near(truth: dict[str, Any], point: tuple[float, float, float], tol_m: float) -> bool:
    return math.dist((truth["x"], truth["y"], truth["z"]), point) < tol_m


@pytest.mark.timeout(300)
def test_drone_2_fly_to_waypoint_3_reaches_it_and_says_so(tmp_path: Path) -> None:
    node = node_exe()
    env = {"UAVC_SIM_BASE_ADDR": fresh_address(), "UAVC_VEHICLES": "process"}
    args = ["--world", "outdoor", "--fleet", "2"]
    with serve(args, tmp_path, token=TOKEN, env=env, drones=("uav1", "uav2")) as srv:
        ros = roslibpy.Ros(srv.ws)
        ros.run(timeout=10)
        replies: list[dict[str, Any]] = []
        roslibpy.Topic(ros, "/console/reply", "uav_console/Reply").subscribe(replies.append)
        try:
            said = srv.say("drone 2, take off")
            assert said == {
                "reply": "uav2: Taking off.",
                "commands": [{"action": "takeoff"}],
                "accepted": True,
                "expects": "",
            }, said
            srv.wait_truth(lambda t: t["flying"] and t["z"] > 0.5, 30, "uav2 airborne", "uav2")
            wait_for(
                lambda: srv.http.get("/api/v1/drones/uav2").json()["task"]["state"],
                lambda state: state == "idle",
                30,
                "uav2's take-off to finish",
            )
            said = srv.say("drone 2, fly to waypoint 3")
            assert said["accepted"] and said["reply"] == "uav2: Flying to waypoint 3.", said
            assert said["commands"] == [{"action": "goto", "waypoint": 3}]
            srv.wait_truth(lambda t: near(t, WP3, 0.5), 60, "uav2 at waypoint 3", "uav2")
            done = wait_for(
                lambda: [m for m in replies if m["drone"] == "uav2"],
                lambda r: any(m["text"] == "Reached waypoint 3" for m in r),
                20,
                "uav2 to say it reached waypoint 3",
            )
            heard = [m["text"] for m in done]
            assert not any("lost sight" in t or "no longer see" in t for t in heard), heard
            assert not any(t.startswith("I could not") for t in heard), heard
            assert near(srv.truth("uav2"), WP3, 0.5)  # it holds there
            assert not srv.truth("uav1")["flying"]  # the other drone was not addressed

            # the GPS of the flying drone, as a third party reads it
            url = f"ws://127.0.0.1:{srv.port}/rosbridge?token={TOKEN}"
            out = subprocess.run(
                # a GPS panel's subscription (every topic, cameras included, is
                # tests/recorder/test_foxglove.py's)
                [node, "foxglove_client.mjs", "live", url, "3", "/ardrone/navdata_gps$"],
                cwd=NODE_DIR,
                capture_output=True,
                text=True,
                timeout=60,
            )
            live = json.loads(out.stdout or "{}")
            assert out.returncode == 0 and "fatal" not in live, (live, out.stderr[-2000:])
            gps = live["topics"]["/uav2/ardrone/navdata_gps"]
            assert gps["type"] == "ardrone_autonomy/navdata_gps" and gps["parsed"], gps
            assert gps["count"] >= 10 and "error" not in gps, gps  # 5 fixes a second
            sample = gps["sample"]
            o = load_world("outdoor").gps_origin
            assert o is not None
            lat, lon, alt = sample["latitude"], sample["longitude"], sample["elevation"]
            e, n, _ = pymap3d.geodetic2enu(lat, lon, alt, o.lat_deg, o.lon_deg, o.alt_m)
            assert math.hypot(e - WP3[0], n - WP3[1]) < 3.0, (e, n)
            assert len(sample["channels"]) == 12 and sample["nbsat"] == 9
            assert sample["tag"] == 27 and sample["size"] == 216

            assert srv.say("drone 2, land")["accepted"]
            srv.wait_truth(lambda t: not t["flying"], 30, "uav2 landed", "uav2")
        finally:
            ros.close()
        assert "Traceback" not in srv.log()
