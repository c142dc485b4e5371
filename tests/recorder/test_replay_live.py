"""Replay in the running console (server/recorder/replay_live.py), REST over ASGI.

A console with no drone and a recordings directory holding a synthetic flight: the flight
opens as a replay under ``/api/v1/replays/{id}``, plays on a graph of its own (the live graph
never sees its messages), answers every command with 409, and unknown flights with 404.
"""

from __future__ import annotations

from pathlib import Path

import httpx

from server.app import create_app
from server.settings import Settings
from tests.app_client import embedded
from tests.recorder.synthetic import write_flight

PILOT = "replay-live-pilot"
OBSERVER = "replay-live-observer"


async def test_a_recorded_flight_replays_read_only_beside_the_live_graph(tmp_path: Path) -> None:
    path = write_flight(tmp_path / "flights", seconds=6.0)
    fid = path.stem
    settings = Settings(
        data_dir=tmp_path, drone="none", recorder=False, token=PILOT, observer_token=OBSERVER
    )
    app = create_app(embedded(settings))
    async with app.router.lifespan_context(app):
        live = app.state.runtime.graph
        seen_live: list[str] = []
        live.add_tap(lambda topic, _type, _msg: seen_live.append(topic))
        async with httpx.AsyncClient(
            transport=httpx.ASGITransport(app=app),
            base_url="http://console",
            headers={"Authorization": f"Bearer {PILOT}"},
        ) as http:
            base = f"/api/v1/replays/{fid}"
            status = (await http.get(f"{base}/replay")).json()
            assert status["id"] == fid and status["drones"] == ["uav1"]
            assert 5.0 < status["duration_s"] < 7.0  # the flight, not more
            paused = await http.post(f"{base}/replay", json={"action": "pause"})
            assert paused.json()["playing"] is False
            end = await http.post(f"{base}/replay", json={"action": "seek", "position_s": 99})
            assert end.json()["position_s"] == status["duration_s"]
            (drone,) = (await http.get(f"{base}/drones")).json()
            assert drone["name"] == "uav1" and drone["replay"] is True
            assert drone["simulated"] is False  # no training faults on a replay
            assert (await http.get(f"{base}/drones/uav1")).json()["battery_pct"] < 90
            assert (await http.get(f"{base}/drones/uav9")).status_code == 404
            world = (await http.get(f"{base}/world")).json()
            assert world["name"] and world["markers"]
            for action in ("takeoff", "land", "emergency", "hover"):
                refused = await http.post(f"{base}/drones/uav1/{action}")
                assert refused.status_code == 409 and "replay" in refused.json()["detail"]
            unknown = await http.get("/api/v1/replays/20200101T000000Z/replay")
            assert unknown.status_code == 404
            bad = await http.get("/api/v1/replays/..%2F..%2Fetc/replay")
            assert bad.status_code == 404
            nobody = await http.get(f"{base}/replay", headers={"Authorization": "Bearer x"})
            assert nobody.status_code == 401
            observer = await http.get(
                f"{base}/drones", headers={"Authorization": f"Bearer {OBSERVER}"}
            )
            assert observer.status_code == 200
        hub = app.state.replays
        assert hub.open_ids == [fid]
        session = await hub.get(fid)
        assert session.graph is not live
        assert session.player.latest  # the replay's graph carries the recording
        assert not any(t.startswith("/ardrone/") or t == "/uav/pose" for t in seen_live)
        assert session.bridge.security.role_for(PILOT).value == "observer"
        assert session.bridge.security.lease is not app.state.runtime.security.lease
    assert hub.open_ids == []  # closed with the console
