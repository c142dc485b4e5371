"""``GET /api/v1/tts?text=…``: a reply spoken by the server, as WAV.

Browsers without voices (Chromium on Linux without speech-dispatcher: an empty
``speechSynthesis.getVoices()``) cannot speak replies; the console then plays this instead. The
voice is hibari-tts's neural voice where the ``speech`` extra is installed, else espeak-ng
(:mod:`server.speech.synth`); the ``X-Voice`` header names it. The voice is loaded on the first
request (the page's probe), in a thread, and every synthesis runs in a thread too: the event
loop never waits on it. Without any voice the endpoint answers 503 and says so, and the page
tells the operator that replies are shown but not spoken.
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response
from starlette.datastructures import State

from server.api.deps import RoleDep
from server.api.models import BINARY
from server.speech.errors import SynthesisError
from server.speech.synth import Voice, best_voice, espeak

router = APIRouter(tags=["speech output"])

MAX_CHARS = 400  # a reply is one or two sentences; longer text is not a reply
MAX_CONCURRENT = 2  # syntheses at once (threads or processes); more at once is a flood
NO_VOICE = "the server has no speech engine (install hibari-tts or espeak-ng)"


def espeak_path() -> str | None:
    """The espeak-ng executable, or None when it is not installed."""
    voice = espeak()
    return voice.exe if voice else None


async def server_voice(state: State) -> Voice | None:
    """The app's voice, loaded once (per app: no module-level mutable state)."""
    lock = getattr(state, "tts_lock", None)
    if lock is None:
        lock = state.tts_lock = asyncio.Lock()
    async with lock:
        if not getattr(state, "tts_loaded", False):
            state.tts_voice = await asyncio.to_thread(best_voice)
            state.tts_loaded = True
    voice: Voice | None = state.tts_voice
    return voice


@router.get("/tts", response_class=Response, responses={200: {"content": {"audio/wav": BINARY}}})
async def tts(
    request: Request, _role: RoleDep, text: str = Query(min_length=1, max_length=MAX_CHARS)
) -> Response:
    """``text`` spoken in English as a WAV file (503 when the server has no speech engine)."""
    state = request.app.state
    running = int(getattr(state, "tts_running", 0))
    if running >= MAX_CONCURRENT:
        raise HTTPException(
            status_code=429,
            detail=f"at most {MAX_CONCURRENT} replies are synthesised at once; try again",
            headers={"Retry-After": "1"},
        )
    state.tts_running = running + 1  # one event loop: nothing runs between check and increment
    try:
        voice = await server_voice(state)
        if voice is None:
            raise HTTPException(status_code=503, detail=NO_VOICE)
        try:
            wav = await asyncio.to_thread(voice.wav, text)
        except SynthesisError as exc:
            raise HTTPException(status_code=503, detail=str(exc)) from exc
    finally:
        state.tts_running -= 1
    headers = {"Cache-Control": "no-store", "X-Voice": voice.name}
    return Response(content=wav, media_type="audio/wav", headers=headers)
