"""Replies spoken by the server (``GET /api/v1/tts``): hibari-tts's neural voice where it is
installed, espeak-ng where it is not, and a clear 503 with neither; synthesis never runs on
the event loop."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import threading
import wave
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from server.app import create_app
from server.settings import Settings
from server.speech.audio import read_wav
from server.speech.recognizer import Recognizer
from tests.app_client import embedded
from tests.speech.conftest import HAVE_TTS

PILOT = "tts-pilot"
ROOT = Path(__file__).resolve().parents[2]


def wav_rate(data: bytes) -> tuple[int, float]:
    """(sample rate, seconds) of a WAV file's bytes."""
    with wave.open(io.BytesIO(data)) as w:
        return w.getframerate(), w.getnframes() / w.getframerate()


@pytest.fixture
async def api(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
    app = create_app(embedded(Settings(data_dir=tmp_path, token=PILOT, drone="none")))
    async with (
        app.router.lifespan_context(app),
        httpx.AsyncClient(
            transport=httpx.ASGITransport(app=app),
            base_url="http://127.0.0.1:8000",  # no socket: Settings' default host and port
            headers={"Authorization": f"Bearer {PILOT}"},
            timeout=60,
        ) as client,
    ):
        client.app = app  # type: ignore[attr-defined]
        yield client


async def test_replies_are_spoken_in_the_neural_voice(
    api: httpx.AsyncClient, recognizer: Recognizer
) -> None:
    pytest.importorskip("hibari")
    r = await api.get("/api/v1/tts", params={"text": "Take off."})
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "audio/wav" and r.headers["x-voice"] == "hibari (heart)"
    rate, seconds = wav_rate(r.content)
    assert rate == 24000 and 0.3 < seconds < 3  # hibari's 24 kHz (espeak-ng writes 22050)
    # It is speech: the console's own recogniser hears the words.
    rec = recognizer.recognize(read_wav(r.content))
    assert rec.commands == [{"action": "takeoff"}], rec
    # Text that starts like an option is spoken, not read as one.
    dash = await api.get("/api/v1/tts", params={"text": "-v Battery low. Returning home."})
    assert dash.status_code == 200 and wav_rate(dash.content)[1] > 1.0


async def test_synthesis_runs_off_the_event_loop(api: httpx.AsyncClient) -> None:
    """A voice that blocks until the server has answered another request: on the event loop
    it would block that answer too, and the voice would time out."""
    answered = threading.Event()
    loop_thread = threading.get_ident()

    class BlockingVoice:
        name = "blocking"
        thread = 0

        def wav(self, text: str) -> bytes:
            BlockingVoice.thread = threading.get_ident()
            if not answered.wait(10.0):
                raise AssertionError("the event loop was blocked by the synthesis")
            return b"RIFF" + bytes(40)

    state = api.app.state  # type: ignore[attr-defined]
    state.tts_voice, state.tts_loaded = BlockingVoice(), True
    import asyncio

    speaking = asyncio.create_task(api.get("/api/v1/tts", params={"text": "hello"}))
    health = await api.get("/api/v1/health")
    assert health.status_code == 200
    answered.set()
    r = await speaking
    assert r.status_code == 200 and r.headers["x-voice"] == "blocking"
    assert BlockingVoice.thread not in (0, loop_thread)


# Run in a process of its own where ``import hibari`` fails as it does when the package is not
# installed (Python's documented meaning of a None entry in sys.modules).
_WITHOUT_HIBARI = """
import asyncio, io, sys, wave
sys.modules["hibari"] = None
import httpx
from server.app import create_app
from server.settings import Settings

async def main():
    settings = Settings(
        data_dir=sys.argv[1], token="p", drone="none", vehicles="inline", asr_preload=False
    )
    app = create_app(settings)
    async with app.router.lifespan_context(app):
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app),
                base_url="http://127.0.0.1:8000", headers={"Authorization": "Bearer p"}) as c:
            r = await c.get("/api/v1/tts", params={"text": "Landing."})
            rate = wave.open(io.BytesIO(r.content)).getframerate() if r.status_code == 200 else 0
            print(r.status_code, r.headers.get("x-voice"), rate, r.text[:200] if rate == 0 else "")

asyncio.run(main())
"""


def _run_without_hibari(tmp_path: Path, path: str) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT), PATH=path)
    done = subprocess.run(
        [sys.executable, "-c", _WITHOUT_HIBARI, str(tmp_path)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip().splitlines()[-1]


@pytest.mark.skipif(not HAVE_TTS, reason="espeak-ng is needed")
def test_without_hibari_espeak_ng_speaks(tmp_path: Path) -> None:
    out = _run_without_hibari(tmp_path, os.environ.get("PATH", ""))
    assert out == "200 espeak-ng 22050", out


def test_without_any_voice_the_answer_says_why(tmp_path: Path) -> None:
    out = _run_without_hibari(tmp_path, str(tmp_path / "nothing-here"))
    assert out.startswith("503 None 0") and "hibari-tts or espeak-ng" in out, out
