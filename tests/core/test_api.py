"""REST API against the real app: simulator on loopback, real driver, real vehicle stack."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import httpx

from tests.core.conftest import OBSERVER
from tests.support.polling import until_async


async def wait_for(
    client: httpx.AsyncClient,
    path: str,
    pred: Callable[[dict[str, Any]], bool],
    timeout: float = 20,
) -> dict[str, Any]:
    """GET ``path`` until ``pred`` holds for its body (the simulator runs in real time here)."""

    async def body() -> dict[str, Any] | None:
        got: dict[str, Any] = (await client.get(path)).json()
        return got if pred(got) else None

    found: dict[str, Any] = await until_async(body, timeout, f"{path} to satisfy the condition")
    return found


async def test_health_needs_no_token_and_reports_parts(api: httpx.AsyncClient) -> None:
    r = await api.get("/api/v1/health", headers={"Authorization": ""})
    assert r.status_code == 200
    body = r.json()
    assert set(body) == {"status", "version", "drones", "captioner", "bus"}
    assert list(body["drones"]) == ["uav1"]
    assert body["bus"] is None  # drones in the web process: no bus router (docs/bus.md)


async def test_an_inline_control_thread_keeps_normal_scheduling(api: httpx.AsyncClient) -> None:
    """Real-time scheduling is for a vehicle process's control thread (tests/isolation), not
    for a thread of the web process."""
    drone = await wait_for(api, "/api/v1/drones/uav1", lambda d: d["controller"] is not None)
    assert drone["controller"]["scheduling"] == "normal"


async def test_tokens_and_roles(api: httpx.AsyncClient) -> None:
    assert (await api.get("/api/v1/world", headers={"Authorization": ""})).status_code == 401
    bad = await api.get("/api/v1/world", headers={"Authorization": "Bearer nope"})
    assert bad.status_code == 401
    obs = {"Authorization": f"Bearer {OBSERVER}"}
    world = (await api.get("/api/v1/world", headers=obs)).json()
    assert len(world["markers"]) >= 12
    assert {"bounds", "stations", "gps_origin"} <= set(world)
    refused = await api.post("/api/v1/drones/uav1/takeoff", headers=obs)
    assert refused.status_code == 403
    assert "observer" in refused.json()["detail"]
    assert (await api.get(f"/api/v1/world?token={OBSERVER}", headers={})).status_code == 200


async def test_unknown_drone_and_bad_bodies_get_clear_errors(api: httpx.AsyncClient) -> None:
    r = await api.get("/api/v1/drones/uav9")
    assert r.status_code == 404
    assert "uav1" in r.json()["detail"]
    assert (await api.post("/api/v1/drones/uav1/fly-away")).status_code == 422
    assert (await api.post("/api/v1/command", json={"text": 5})).status_code == 422
    assert (await api.post("/api/v1/command", json={"text": "x" * 5000})).status_code == 422
    assert (await api.post("/api/v1/command", content=b"{not json")).status_code == 422
    assert (await api.post("/api/v1/interpret", json={"txt": "land"})).status_code == 422
    fault = await api.post("/api/v1/sim/uav1/fault", json={"kind": "meteor"})
    assert fault.status_code == 422


async def test_takeoff_hover_land_over_the_real_protocol(api: httpx.AsyncClient) -> None:
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    assert (await api.post("/api/v1/drones/uav1/takeoff")).json()["accepted"]
    truth = await wait_for(api, "/api/v1/sim/uav1/truth", lambda t: t["z"] > 0.6)
    assert truth["flying"]
    tele = await wait_for(api, "/api/v1/drones/uav1", lambda d: d["altitude_m"] > 0.5)
    assert tele["ctrl_state"] in {"HOVERING", "FLYING", "TAKEOFF"}
    await api.post("/api/v1/drones/uav1/land")
    await wait_for(api, "/api/v1/sim/uav1/truth", lambda t: not t["flying"] and t["z"] < 0.05)


async def test_emergency_cuts_the_motors(api: httpx.AsyncClient) -> None:
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    await api.post("/api/v1/drones/uav1/takeoff")
    await wait_for(api, "/api/v1/sim/uav1/truth", lambda t: t["z"] > 0.4)
    await api.post("/api/v1/drones/uav1/emergency")
    truth = await wait_for(api, "/api/v1/sim/uav1/truth", lambda t: t["emergency"])
    assert truth["ctrl_state"] in {"DEFAULT", "LANDED", "EMERGENCY"} or truth["emergency"]


async def test_link_loss_fault_is_seen_and_recovers(api: httpx.AsyncClient) -> None:
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    r = await api.post("/api/v1/sim/uav1/fault", json={"kind": "link_loss", "duration_s": 8.0})
    assert r.status_code == 200
    await wait_for(api, "/api/v1/drones/uav1", lambda d: not d["link_ok"])
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])


async def test_training_faults_drain_and_lost_markers(api: httpx.AsyncClient) -> None:
    """The training panel's faults (docs/flying.md): a leak, lost markers, and their bounds."""
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    before = (await api.get("/api/v1/sim/uav1/truth")).json()["battery_pct"]
    drain = {"kind": "battery_drain", "drain_pct_s": 1.5}
    assert (await api.post("/api/v1/sim/uav1/fault", json=drain)).status_code == 200
    await wait_for(api, "/api/v1/sim/uav1/truth", lambda t: t["battery_pct"] < before - 1.0)
    lost = {"kind": "lost_markers", "duration_s": 2.0}
    assert (await api.post("/api/v1/sim/uav1/fault", json=lost)).status_code == 200
    assert (await api.post("/api/v1/sim/uav1/fault", json={"kind": "clear"})).status_code == 200
    too_fast = {"kind": "battery_drain", "drain_pct_s": 50}
    assert (await api.post("/api/v1/sim/uav1/fault", json=too_fast)).status_code == 422
    no_rate = {"kind": "battery_drain"}
    assert (await api.post("/api/v1/sim/uav1/fault", json=no_rate)).status_code == 422


async def test_openapi_documents_the_interface(api: httpx.AsyncClient) -> None:
    spec = (await api.get("/openapi.json")).json()
    paths = set(spec["paths"])
    for p in (
        "/api/v1/health",
        "/api/v1/world",
        "/api/v1/interpret",
        "/api/v1/command",
        "/api/v1/drones",
        "/api/v1/drones/{drone_id}",
        "/api/v1/drones/{drone_id}/{action}",
        "/api/v1/drones/{drone_id}/describe",
        "/api/v1/drones/{drone_id}/video.mjpg",
        "/api/v1/sim/{drone_id}/truth",
        "/api/v1/sim/{drone_id}/fault",
        "/version",
    ):
        assert p in paths, p
    assert (await api.get("/docs")).status_code == 200


async def test_interpret_is_nlu_only(api: httpx.AsyncClient) -> None:
    r = await api.post("/api/v1/interpret", json={"text": "take off and climb half a metre"})
    assert r.json() == {
        "text": "take off and climb half a metre",
        "commands": [{"action": "takeoff"}, {"action": "move", "direction": "up", "distance": 0.5}],
    }
    assert (await api.post("/api/v1/interpret", json={"text": "blorp"})).json()["commands"] == []
    bad_state = await api.post("/api/v1/interpret", json={"text": "land", "state": "DANCING"})
    assert bad_state.status_code == 422


async def test_command_goes_through_the_dialog_and_flies(api: httpx.AsyncClient) -> None:
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    refused = (await api.post("/api/v1/command", json={"text": "move forward one meter"})).json()
    assert refused["accepted"] is False
    assert "take off" in refused["reply"].lower()
    unsure = await api.post("/api/v1/command", json={"text": "take off", "confidence": 0.2})
    assert unsure.json()["accepted"] is False and "repeat" in unsure.json()["reply"]
    # Heard with middling confidence: read back, and the spoken "yes" runs it.
    asked = (await api.post("/api/v1/command", json={"text": "take off", "confidence": 0.4})).json()
    assert asked["accepted"] is False and asked["reply"].startswith('Did you say "take off"?')
    assert asked["expects"] == "confirm" and unsure.json()["expects"] == ""
    ok = (await api.post("/api/v1/command", json={"text": "yes", "confidence": 0.9})).json()
    assert ok["accepted"] is True and ok["expects"] == ""
    assert ok["commands"] == [{"action": "takeoff"}]
    await wait_for(api, "/api/v1/sim/uav1/truth", lambda t: t["z"] > 0.6)
    obs = {"Authorization": f"Bearer {OBSERVER}"}
    as_observer = await api.post("/api/v1/command", json={"text": "land"}, headers=obs)
    assert as_observer.status_code == 403
    landed = (await api.post("/api/v1/command", json={"text": "land"})).json()
    assert landed["accepted"] is True
    await wait_for(api, "/api/v1/sim/uav1/truth", lambda t: not t["flying"])


async def test_describe_captions_the_camera_and_says_why_not(api: httpx.AsyncClient) -> None:
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    health = (await api.get("/api/v1/health")).json()
    r = await api.post("/api/v1/drones/uav1/describe")
    if health["captioner"] == "ready":
        assert r.status_code == 200
        body = r.json()
        assert body["drone"] == "uav1" and len(body["text"].split()) >= 2
    else:
        assert r.status_code == 503 and "unavailable" in r.json()["detail"]


async def test_describe_without_a_model_degrades_clearly(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from server.app import create_app
    from server.settings import Settings
    from tests.app_client import embedded
    from tests.core.conftest import PILOT

    (tmp_path / "model").mkdir()
    settings = Settings(
        data_dir=tmp_path,
        token=PILOT,
        observer_token="o" * 20,
        drone="none",
        model_dir=tmp_path / "model",
    )
    app = create_app(embedded(settings))
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as client:
            health = (await client.get("/api/v1/health")).json()
            assert health["status"] == "degraded"
            assert health["captioner"].startswith("Scene description is unavailable")


async def test_missions_need_a_pilot_and_are_validated(api: httpx.AsyncClient) -> None:
    obs = {"Authorization": f"Bearer {OBSERVER}"}
    assert (await api.get("/api/v1/missions", headers=obs)).status_code == 200
    route = {"markers": [1, 4], "altitude_m": 1.4}
    assert (await api.post("/api/v1/missions", json=route, headers=obs)).status_code == 403
    bad = await api.post("/api/v1/missions", json={"markers": [42]})
    assert bad.status_code == 422
    assert (await api.get("/api/v1/missions/no-such-mission")).status_code == 404
    fleet = (await api.get("/api/v1/fleet")).json()
    assert [d["name"] for d in fleet["drones"]] == ["uav1"]


async def test_rest_respects_the_pilot_lease_but_never_blocks_safety(
    api: httpx.AsyncClient,
) -> None:
    runtime = api.app.state.runtime  # type: ignore[attr-defined]
    told: list[str] = []
    runtime.security.lease.acquire("browser-pilot", 0.0, on_revoke=told.append)
    held = await api.post("/api/v1/drones/uav1/takeoff")
    assert held.status_code == 409 and "take_over" in held.json()["detail"]
    assert (await api.post("/api/v1/command", json={"text": "take off"})).status_code == 409
    # The holder id is not a credential (rosapi lists connections): only the holding's secret.
    as_id = {"X-Pilot-Lease": "browser-pilot"}
    assert (await api.post("/api/v1/drones/uav1/reset", headers=as_id)).status_code == 409
    as_holder = {"X-Pilot-Lease": runtime.security.lease.key_of("browser-pilot")}
    assert (await api.post("/api/v1/drones/uav1/reset", headers=as_holder)).status_code == 200
    for safety in ("land", "emergency", "hover"):
        assert (await api.post(f"/api/v1/drones/uav1/{safety}")).status_code == 200
    assert (await api.post("/api/v1/command", json={"text": "land now"})).status_code == 200
    took = await api.post("/api/v1/drones/uav1/reset?take_over=true")
    assert took.status_code == 200
    # REST keeps the lease it took: the page must take it back explicitly (issue 14).
    assert told == ["rest"]
    assert runtime.security.lease.state.holder == "rest"
    assert (await api.post("/api/v1/drones/uav1/reset")).status_code == 200
