"""The speech routes in-process: the model loads on first use unless preloaded (``serve``)."""

from __future__ import annotations

from pathlib import Path

import httpx

from server.app import create_app
from server.settings import Settings
from tests.app_client import embedded
from tests.speech.conftest import Synth

PILOT = "speech-app-pilot"


async def test_model_loads_on_first_use_and_no_drone_is_a_clear_404(
    tmp_path: Path, synth: Synth
) -> None:
    app = create_app(embedded(Settings(data_dir=tmp_path, token=PILOT, drone="none")))
    async with (
        app.router.lifespan_context(app),
        httpx.AsyncClient(
            transport=httpx.ASGITransport(app=app),
            base_url="http://127.0.0.1:8000",  # no socket: Settings' default host and port
            headers={"Authorization": f"Bearer {PILOT}"},
            timeout=120,
        ) as client,
    ):
        status = (await client.get("/api/v1/speech/status")).json()
        assert status["status"] == "loads on first use" and status["recognizer"] == "auto"
        wav = synth("go to marker four", voice="en-gb-x-rp", speed=160).read_bytes()
        headers = {"Content-Type": "audio/wav"}
        r = await client.post("/api/v1/speech?execute=false", content=wav, headers=headers)
        assert r.status_code == 200, r.text
        assert r.json()["commands"] == [{"action": "goto", "marker": 4}]
        assert (await client.get("/api/v1/speech/status")).json()["status"] == "ready"
        r = await client.post("/api/v1/speech", content=wav, headers=headers)
        assert r.status_code == 404 and "no drone" in r.json()["detail"]
        assert (await client.get("/api/v1/speech/status")).status_code == 200
        unauth = await client.get("/api/v1/speech/status", headers={"Authorization": ""})
        assert unauth.status_code == 401
