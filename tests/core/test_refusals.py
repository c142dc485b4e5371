"""Direct actions over REST (issue 18): refusals say why with ``accepted: false`` and the way
out, nothing is sent to the drone, and every action is audited with where it came from."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from server.app import create_app
from server.settings import Settings
from tests.app_client import app_fixture, embedded
from tests.core.conftest import OBSERVER, PILOT
from tests.core.test_api import wait_for
from tests.support.loopback import fresh_address
from tests.support.polling import until_async

# The app on a simulator of its own (a fresh loopback address per test).
api = app_fixture(PILOT, OBSERVER, sim_speed=4.0)


async def test_takeoff_in_emergency_and_at_low_battery_is_refused_with_the_way_out(
    api: httpx.AsyncClient,
) -> None:
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["link_ok"])
    runtime = api.app.state.runtime  # type: ignore[attr-defined]
    stop = await api.post("/api/v1/drones/uav1/emergency", headers={"X-Command-Source": "keyboard"})
    assert stop.json()["accepted"] is True
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["emergency"])
    r = (
        await api.post("/api/v1/drones/uav1/takeoff", headers={"X-Command-Source": "button"})
    ).json()
    assert r["accepted"] is False and "emergency" in r["detail"] and "Reset" in r["detail"]
    # Nothing was sent: the simulated drone stays on the floor.
    truth = (await api.get("/api/v1/sim/uav1/truth")).json()
    assert not truth["flying"]
    # The refusal was said to every console, and typed "take off" gets the same answer first.
    dialog = runtime.dialogs["uav1"]
    assert dialog.replies[-1]["text"] == r["detail"] and dialog.replies[-1]["level"] == "warn"
    said = (await api.post("/api/v1/command", json={"text": "take off"})).json()
    assert said["accepted"] is False and not said["reply"].startswith("Taking off")
    assert "Reset" in said["reply"]
    # Reset, then the battery at 11 %: refused with the numbers.
    assert (await api.post("/api/v1/drones/uav1/reset")).json()["accepted"]
    await wait_for(api, "/api/v1/drones/uav1", lambda d: not d["emergency"])
    await api.post("/api/v1/sim/uav1/fault", json={"kind": "battery", "battery_pct": 11})
    await wait_for(api, "/api/v1/drones/uav1", lambda d: d["battery_pct"] <= 11.5)
    low = (await api.post("/api/v1/drones/uav1/takeoff")).json()
    assert low["accepted"] is False and "11 %" in low["detail"]

    # Every action is in the audit log with its source, refused or not (written on the log's
    # own thread, after the command reached the drone).
    def seen() -> set[tuple[str, str, str]]:
        rows = runtime.audit.recent(20, drone="uav1")
        return {(e.commands[0]["action"], e.source, e.action) for e in rows if e.commands}

    await until_async(lambda: ("takeoff", "rest", "refused") in seen(), 10.0, "the REST refusal")
    assert ("emergency", "keyboard", "executed") in seen()
    assert ("takeoff", "button", "refused") in seen()
    assert ("takeoff", "rest", "refused") in seen()
    assert ("reset", "rest", "executed") in seen()


async def test_server_speaks_replies_as_wav_or_says_why_not(api: httpx.AsyncClient) -> None:
    from server.api.tts import espeak_path

    r = await api.get("/api/v1/tts", params={"text": "-v Battery low. Returning home."})
    if espeak_path() is None:
        assert r.status_code == 503 and "espeak-ng" in r.json()["detail"]
        return
    assert r.status_code == 200 and r.headers["content-type"] == "audio/wav"
    assert r.content[:4] == b"RIFF" and r.content[8:12] == b"WAVE" and len(r.content) > 8000
    assert (await api.get("/api/v1/tts", params={"text": "x" * 401})).status_code == 422
    assert (await api.get("/api/v1/tts")).status_code == 422
    anon = await api.get("/api/v1/tts", params={"text": "hi"}, headers={"Authorization": ""})
    assert anon.status_code == 401
    # A flood gets 429 (each reply is a process), and the server keeps answering.
    many = await asyncio.gather(
        *(api.get("/api/v1/tts", params={"text": f"reply number {i}"}) for i in range(6))
    )
    codes = sorted(r.status_code for r in many)
    assert codes.count(200) >= 2 and codes.count(429) >= 1 and set(codes) <= {200, 429}, codes
    assert (await api.get("/api/v1/tts", params={"text": "still here"})).status_code == 200


@pytest.fixture
async def fleet_api(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
    """Two simulated drones on fresh loopback addresses."""
    settings = Settings(
        data_dir=tmp_path,
        token=PILOT,
        observer_token=OBSERVER,
        sim_base_addr=fresh_address(2),
        sim_speed=4.0,
        fleet=2,
    )
    app = create_app(embedded(settings))
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(
            transport=transport,
            base_url="http://127.0.0.1:8000",  # no socket: Settings' default host and port
            headers={"Authorization": f"Bearer {PILOT}"},
        ) as client:
            yield client


async def test_sentences_name_their_drone(fleet_api: httpx.AsyncClient) -> None:
    api = fleet_api
    for name in ("uav1", "uav2"):
        await wait_for(api, f"/api/v1/drones/{name}", lambda d: d["link_ok"])
    r = (await api.post("/api/v1/command", json={"text": "uav2 take off"})).json()
    assert (
        r["accepted"]
        and r["reply"] == "uav2: Taking off."
        and r["commands"] == [{"action": "takeoff"}]
    )
    await wait_for(api, "/api/v1/sim/uav2/truth", lambda t: t["z"] > 0.4)
    assert not (await api.get("/api/v1/sim/uav1/truth")).json()["flying"]
    both = (await api.post("/api/v1/command", json={"text": "all drones land"})).json()
    assert both["reply"].startswith("uav1: ") and "uav2: Landing." in both["reply"]
    await wait_for(api, "/api/v1/sim/uav2/truth", lambda t: not t["flying"])
    missing = await api.post("/api/v1/command", json={"text": "drone 7, land"})
    assert missing.status_code == 404 and "uav7" in missing.json()["detail"]
