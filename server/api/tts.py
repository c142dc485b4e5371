"""``GET /api/v1/tts?text=…``: a reply spoken by the server, as WAV (espeak-ng).

Browsers without voices (Chromium on Linux without speech-dispatcher: an empty
``speechSynthesis.getVoices()``) cannot speak replies; the console then plays this instead.
espeak-ng (Debian package ``espeak-ng``) writes a WAV to stdout with ``--stdout``; it is
offline and fast (a sentence in tens of milliseconds). Without it the endpoint answers 503 and
says so, and the page tells the operator that replies are shown but not spoken.
"""

from __future__ import annotations

import asyncio
import shutil

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response

from server.api.deps import RoleDep

router = APIRouter(tags=["speech output"])

MAX_CHARS = 400  # a reply is one or two sentences; longer text is not a reply
TIMEOUT_S = 10.0
WORDS_PER_MINUTE = 165  # espeak-ng's default is 175; a touch slower is clearer over a fan's noise
MAX_CONCURRENT = 2  # each request is a process; more than this at once is a flood, not replies


def espeak_path() -> str | None:
    """The espeak-ng executable, or None when it is not installed."""
    return shutil.which("espeak-ng")


@router.get("/tts", response_class=Response, responses={200: {"content": {"audio/wav": {}}}})
async def tts(
    request: Request, _role: RoleDep, text: str = Query(min_length=1, max_length=MAX_CHARS)
) -> Response:
    """``text`` spoken in English as a WAV file (503 when the server has no speech engine)."""
    exe = espeak_path()
    if exe is None:
        raise HTTPException(
            status_code=503, detail="the server has no speech engine (install espeak-ng)"
        )
    state = request.app.state  # per app, not per process: no module-level mutable state
    running = int(getattr(state, "tts_running", 0))
    if running >= MAX_CONCURRENT:
        raise HTTPException(
            status_code=429,
            detail=f"at most {MAX_CONCURRENT} replies are synthesised at once; try again",
            headers={"Retry-After": "1"},
        )
    state.tts_running = running + 1  # one event loop: nothing runs between check and increment
    try:
        return await _synthesise(exe, text)
    finally:
        state.tts_running -= 1


async def _synthesise(exe: str, text: str) -> Response:
    # "--" ends the options: text starting with "-" is spoken, never read as a flag.
    proc = await asyncio.create_subprocess_exec(
        exe,
        "--stdout",
        "-v",
        "en-us",
        "-s",
        str(WORDS_PER_MINUTE),
        "--",
        text,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    try:
        wav, err = await asyncio.wait_for(proc.communicate(), timeout=TIMEOUT_S)
    except TimeoutError as exc:
        proc.kill()
        await proc.wait()
        raise HTTPException(status_code=503, detail="speech synthesis timed out") from exc
    if proc.returncode != 0 or not wav.startswith(b"RIFF"):
        why = err.decode(errors="replace").strip()[:200] or f"exit status {proc.returncode}"
        raise HTTPException(status_code=503, detail=f"speech synthesis failed: {why}")
    return Response(content=wav, media_type="audio/wav", headers={"Cache-Control": "no-store"})
