"""The Central patrol (issue 13 item 9) through the whole server: two simulated drones behind
the AR.Drone protocol on loopback addresses of their own, REST ``/api/v1/patrol`` and spoken
commands through the dialog, in real time (the clock the fleet runs on)."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

import httpx
import pytest

from server.fleet.central import world_route
from tests.app_client import app_fixture

PILOT = "pilot-token-central"
OBSERVER = "observer-token-central"


api = app_fixture(PILOT, OBSERVER, fleet=2)


async def _until(api: httpx.AsyncClient, pred: Any, timeout_s: float) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        body: dict[str, Any] = (await api.get("/api/v1/patrol")).json()
        if pred(body) or time.monotonic() > deadline:
            return body
        await asyncio.sleep(0.25)


async def _say(api: httpx.AsyncClient, text: str) -> dict[str, Any]:
    r = await api.post("/api/v1/command", json={"text": text, "drone": "uav1"})
    assert r.status_code == 200, r.text
    return dict(r.json())


def test_indoor_route_faces_each_marker() -> None:
    from drone.sim.world import load_world

    route, heads = world_route(load_world("indoor"))
    assert len(route) == len(heads) == 12
    assert (route[0].x, route[0].y) == pytest.approx((1.5, 1.01))  # 1 m off marker 0's wall
    assert heads[0] == pytest.approx(-90.0)  # facing marker 0 on the south wall
    outdoor, none = world_route(load_world("outdoor"))
    assert len(outdoor) == 4 and none == []  # the field's own waypoints


@pytest.mark.timeout(90)
async def test_start_watch_and_stop_by_rest_and_voice(api: httpx.AsyncClient) -> None:
    # both drones join the fleet (their LTMs report, their navdata has come: a battery level)
    # before anything is started
    def ready(b: dict[str, Any]) -> bool:
        return len(b["drones"]) == 2 and all(
            d["role"] == "idle" and d["battery"] > 0 for d in b["drones"]
        )

    idle = await _until(api, ready, 20.0)
    assert ready(idle), idle
    assert not idle["running"] and idle["mission"] is None

    observer = await api.post("/api/v1/patrol", headers={"Authorization": f"Bearer {OBSERVER}"})
    assert observer.status_code == 403
    r = await api.post("/api/v1/patrol")
    assert r.status_code == 200, r.text
    assert r.json()["reply"].startswith("Starting the patrol of 12 waypoints with 2 drones")
    again = await _say(api, "start the patrol with all drones")
    assert again["reply"].startswith("The patrol is already running")
    assert (await api.post("/api/v1/patrol")).status_code == 409

    # the same live view for rosbridge clients, on the latched /fleet/missions topic
    seen_topic: list[dict[str, Any]] = []
    graph = api.app.state.runtime.graph  # type: ignore[attr-defined]
    graph.subscribe("/fleet/missions", lambda m: seen_topic.append(json.loads(m["data"])))

    # watch: one drone patrols, the other waits; waypoints get visited, the gap is measured
    body = await _until(
        api,
        lambda b: b["mission"] and sum(w["visited"] for w in b["mission"]["coverage"]["waypoints"]),
        45.0,
    )
    roles = sorted(d["role"] for d in body["drones"])
    # one patrols, the other waits: unless a navdata gap on a loaded machine had the CTM
    # replace the first (it then flies home), which is the fleet doing its job
    assert roles in (["idle", "patrolling"], ["patrolling", "returning"]), body["drones"]
    cov = body["mission"]["coverage"]
    seen = [w for w in cov["waypoints"] if w["visited"]]
    assert seen and all(0 <= w["since_last_s"] < 45 for w in seen)
    assert cov["longest_gap_s"] >= max(w["since_last_s"] for w in seen)
    assert all(d["battery"] is not None and 0 < d["battery"] <= 100 for d in body["drones"])
    assert seen_topic and seen_topic[-1]["missions"][0]["id"] == body["mission"]["id"]
    assert len(seen_topic[-1]["missions"][0]["coverage"]["waypoints"]) == 12

    stop = await _say(api, "stop the patrol")
    assert stop["accepted"] and stop["reply"] == "Stopping the patrol; the drones are flying home."
    body = await _until(api, lambda b: not b["running"], 3.0)
    assert not body["running"]
    assert "returning" in {d["role"] for d in body["drones"]}
    gone = await api.delete("/api/v1/patrol")
    assert gone.status_code == 404 and gone.json()["detail"] == "No patrol is running."
    # with no fleet patrol, "stop the patrol" is this drone's own cancel
    plain = await _say(api, "stop the patrol")
    assert plain["reply"] == "OK, cancelled."
