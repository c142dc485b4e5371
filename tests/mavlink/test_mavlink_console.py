"""The whole console on a mixed fleet: ``--drone sim,sim-mavlink --world outdoor --fleet 2``
(uav1 the AR.Drone simulator and uav2 a simulated PX4 on loopback addresses of their own, the real
drivers over UDP and TCP), REST and the graph:
commands in words fly the autopilot, MAVROS topics carry its state, a denial reaches the
operator with the vehicle's reason."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.settings import Settings
from tests.app_client import app_client
from tests.support.loopback import fresh_address
from tests.support.polling import until_async

PILOT = "pilot-token-mavlink"


@pytest.fixture
async def api(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
    settings = Settings(
        data_dir=tmp_path,
        token=PILOT,
        observer_token="observer-mavlink",
        drone="sim,sim-mavlink",
        world="outdoor",
        fleet=2,
        sim_base_addr=fresh_address(2),
        sim_speed=4.0,
    )
    async with app_client(settings) as client:
        yield client


async def test_fleet_of_mavlink_drones_flies_by_words(api: httpx.AsyncClient) -> None:
    runtime = api.app.state.runtime  # type: ignore[attr-defined]
    graph = runtime.graph
    seen: dict[str, list[dict[str, Any]]] = {}
    for topic in (
        "/uav2/mavros/state",
        "/uav2/mavros/global_position/global",
        "/uav2/mavros/battery",
        "/uav2/uav/pose",
        "/console/reply",
        "/uav2/mavros/local_position/pose",
    ):
        graph.subscribe(topic, lambda m, t=topic: seen.setdefault(t, []).append(m))

    async def linked() -> bool:
        r = await api.get("/api/v1/drones/uav2")
        body = r.json()
        return bool(body["link_ok"] and body["extra"].get("home"))

    await until_async(linked, 15.0, "linked")
    body = (await api.get("/api/v1/drones/uav2")).json()
    assert body["extra"]["protocol"] == "mavlink" and body["extra"]["autopilot"] == "PX4"
    assert body["x"] == pytest.approx(1.5, abs=0.05)  # standing on station home2
    await until_async(
        lambda: seen.get("/uav2/mavros/state", [{}])[-1].get("connected"), 5.0, "mavros connected"
    )
    assert seen["/uav2/mavros/state"][-1]["mode"] == "AUTO.LOITER"

    r = await api.post("/api/v1/command", json={"text": "take off", "drone": "uav2"})
    assert r.status_code == 200 and r.json()["accepted"], r.text

    async def flying() -> bool:
        s = (await api.get("/api/v1/drones/uav2")).json()
        return bool(s["flying"] and s["ctrl_state"] in ("HOVERING", "FLYING"))

    await until_async(flying, 20.0, "flying")
    r = await api.post("/api/v1/command", json={"text": "go forward three meters", "drone": "uav2"})
    assert r.json()["accepted"], r.text
    # the world's start yaw is 90° (north): forward is +y in the map frame

    async def moved() -> bool:
        s = (await api.get("/api/v1/drones/uav2")).json()
        return bool(s["y"] > 2.7 and s["task"]["state"] in ("idle", "succeeded"))

    await until_async(moved, 20.0, "moved")
    truth = (await api.get("/api/v1/sim/uav2/truth")).json()
    assert truth["y"] == pytest.approx(3.0, abs=0.3)
    await until_async(lambda: seen["/uav2/mavros/state"][-1]["armed"], 5.0, "mavros armed")
    fix = seen["/uav2/mavros/global_position/global"][-1]
    assert fix["latitude"] > 36.36716 and fix["status"]["status"] == 0
    assert 0.9 < seen["/uav2/mavros/battery"][-1]["percentage"] <= 1.0
    assert seen["/uav2/uav/pose"][-1]["pose"]["position"]["y"] > 2.5
    assert seen["/uav2/mavros/local_position/pose"][-1]["pose"]["position"]["y"] > 2.5

    # The vehicle's own refusal reaches the operator with its reason (disarm in the air).
    stack = runtime.drones["uav2"]
    stack.vehicle.protocol.command(400, 0.0)
    stack.vehicle._track(stack.vehicle.protocol._token, "disarm")
    await until_async(
        lambda: any(
            "Disarming denied: not landed" in m["text"] and m["level"] == "alert"
            for m in seen.get("/console/reply", [])
        ),
        10.0,
        "the refusal's reason in a reply",
    )

    r = await api.post("/api/v1/command", json={"text": "land", "drone": "uav2"})
    assert r.json()["accepted"], r.text

    async def landed() -> bool:
        s = (await api.get("/api/v1/drones/uav2")).json()
        return not s["flying"] and s["ctrl_state"] == "LANDED"

    await until_async(landed, 30.0, "landed")
    # Link loss: the alert names what the autopilot will do on its own.
    r = await api.post("/api/v1/sim/uav2/fault", json={"kind": "link_loss", "duration_s": 12.0})
    assert r.status_code in (200, 204), r.text
    want = "I lost the link to the drone. PX4's data-link-loss failsafe will return to launch"
    await until_async(
        lambda: any(m["text"].startswith(want) for m in seen.get("/console/reply", [])),
        10.0,
        "the link-loss alert",
    )
    await until_async(
        lambda: any("link to the drone is back" in m["text"] for m in seen["/console/reply"]),
        10.0,
        "the link-back reply",
    )

    # uav1, the AR.Drone of the same fleet, is there and never moved
    uav1 = (await api.get("/api/v1/drones/uav1")).json()
    assert "protocol" not in uav1["extra"] and not uav1["flying"]
