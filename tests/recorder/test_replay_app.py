"""The replay app in process (httpx over ASGI): a fleet recording, paused start, read-only."""

from __future__ import annotations

from pathlib import Path

import httpx

from server.graph import Graph
from server.recorder.recorder import Recorder, RecorderConfig
from server.recorder.replay import load
from server.recorder.replay_app import create_replay_app
from server.settings import Settings
from tests.app_client import embedded

from .conftest import NAVDATA, Clock, navdata

TOKEN = "replay-app-token"


def fleet_recording(directory: Path) -> Path:
    graph, clock = Graph(), Clock(1_780_000_000.0)
    rec = Recorder(
        graph,
        RecorderConfig(directory, idle_s=1.0),
        clock=clock,
        stamp_ns=lambda: int(clock.t * 1e9),
    )
    rec.start(background=False)
    for i in range(20):
        graph.publish("/uav1/ardrone/navdata", navdata(3, 90.0 - i), type=NAVDATA)
        graph.publish("/uav2/ardrone/navdata", navdata(3, 50.0 - i), type=NAVDATA)
        clock.t += 0.1
        rec.step()
    for name in ("uav1", "uav2"):
        graph.publish(f"/{name}/ardrone/navdata", navdata(2, 30.0), type=NAVDATA)
    clock.t += 5
    rec.step()
    rec.stop()
    return rec.index.path_for(rec.flights()[0].id)


async def test_a_fleet_replays_as_two_read_only_drones(tmp_path: Path) -> None:
    path = fleet_recording(tmp_path / "flights")
    recording, played = load(path)
    settings = Settings(data_dir=tmp_path / "data", token="hidden-pilot", observer_token=TOKEN)
    app = create_replay_app(path, recording, played, settings=settings)
    app.state.start_paused = True
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        headers = {"Authorization": f"Bearer {TOKEN}"}
        async with httpx.AsyncClient(
            transport=transport, base_url="http://replay", headers=headers
        ) as http:
            status = (await http.get("/api/v1/replay")).json()
            assert not status["playing"] and status["position_s"] == 0
            assert status["drones"] == ["uav1", "uav2"] and status["messages"] == 42
            drones = {d["name"]: d for d in (await http.get("/api/v1/drones")).json()}
            assert drones["uav1"]["battery_pct"] == 90.0  # the state at the start
            assert drones["uav2"]["battery_pct"] == 50.0
            end = await http.post("/api/v1/replay", json={"action": "seek", "position_s": 99})
            assert end.json()["position_s"] == status["duration_s"]
            drones = {d["name"]: d for d in (await http.get("/api/v1/drones")).json()}
            assert drones["uav2"]["battery_pct"] == 30.0 and drones["uav2"]["navdata"]["state"] == 2
            refused = await http.post("/api/v1/drones/uav1/land")
            assert refused.status_code == 403  # the page's token is an observer's
            bad = await http.post("/api/v1/replay", json={"action": "speed", "speed": -1})
            assert bad.status_code == 422
            flights = (await http.get("/api/v1/flights")).json()
            assert flights == {"flights": []}  # a replay records nothing


async def test_recorder_off_records_nothing_and_still_lists(tmp_path: Path) -> None:
    from server.app import create_app

    (tmp_path / "flights").mkdir()
    fleet_recording(tmp_path / "flights")  # a recording from an earlier run
    settings = Settings(data_dir=tmp_path, drone="none", recorder=False, token=TOKEN)
    app = create_app(embedded(settings))
    async with app.router.lifespan_context(app):
        runtime = app.state.runtime
        assert runtime.recorder is None and runtime.audit.recording is None
        runtime.graph.publish("/ardrone/navdata", navdata(3), type=NAVDATA)
        async with httpx.AsyncClient(
            transport=httpx.ASGITransport(app=app),
            base_url="http://live",
            headers={"Authorization": f"Bearer {TOKEN}"},
        ) as http:
            (row,) = (await http.get("/api/v1/flights")).json()["flights"]
            assert row["drones"] == ["uav1", "uav2"] and row["ended"] is not None
    assert len(list((tmp_path / "flights").glob("*.mcap"))) == 1
