"""``POST /api/v1/speech`` (a WAV file -> like ``POST /command``) and the browser's microphone
stream ``WS /api/v1/speech/stream`` (16 kHz PCM in, interim and final text out).

The stream only recognises: the page sends the final text down the same dialog path as typed
text (``/console/utterance`` with ``source: speech`` and the confidence), so the pilot lease,
roles and the dialog manager's "please repeat" apply exactly as for everything else, whichever
process runs the vehicle. The stream itself is refused to observers and to a pilot that does
not hold the lease while another does (close code 1008 with the reason).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import functools
import json
import logging
import time
from collections.abc import Callable
from typing import Annotated, Any, TypeVar

from fastapi import APIRouter, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from pydantic import BaseModel, Field

from server.api.deps import RoleDep, RuntimeDep, check_lease
from server.api.models import CommandList, SpeechStatus
from server.http.security import Role, token_from
from server.http.ws_guard import lift_frame_cap
from server.speech.audio import MAX_REQUEST_S, SAMPLE_RATE, Samples
from server.speech.errors import AudioError, AudioTooLong, Busy, ModelError
from server.speech.recognizer import Recognition, SileroStream
from server.speech.service import SpeechService, decisive
from server.speech.stream import (
    MODES,
    Event,
    Final,
    Interim,
    Problem,
    Speculation,
    StreamSession,
    control_kind,
)

log = logging.getLogger("uav_console.speech")
T = TypeVar("T")
router = APIRouter(tags=["speech"])

WAV_TYPES = frozenset({"audio/wav", "audio/x-wav", "audio/wave", "audio/vnd.wave"})
# 30 s of 48 kHz stereo 16-bit PCM plus headers: anything longer cannot be a valid request.
MAX_BODY_BYTES = int(MAX_REQUEST_S * 48_000 * 2 * 2) + 64 * 1024
MAX_FRAME_BYTES = 64 * 1024  # one stream frame: far more than the worklet's 32 ms chunks
# Interim text every this many seconds of speech. The one decoder of a 2-core machine is busy
# for a whole decode once one starts (a decode cannot be stopped): hands-free, a decode for
# interim text still running when the speech ends holds back the decode that ends the
# utterance, so only speech longer than most commands gets interim text.
PTT_INTERIM_S = 0.8
HANDSFREE_INTERIM_S = 1.6
INBOX_FRAMES = 256  # frames read ahead of the session (8 s of the worklet's 32 ms frames)
STREAM_IDLE_S = 10.0  # a push-to-talk stream that sends nothing for this long is closed
CLOSE_POLICY = 1008  # RFC 6455 §7.4.1
CLOSE_TRY_AGAIN = 1013  # RFC 6455 §7.4.1 (IANA registry): try again later


class SpeechResponse(BaseModel):
    text: str = Field(description="the sentence handed to the dialog (snapped to the grammars)")
    confidence: float
    commands: CommandList
    reply: str = Field(description="the dialog's answer ('' with execute=false)")
    accepted: bool
    heard: str = Field(description="the recogniser's own transcript")
    decode_ms: float
    expects: str = Field(
        "", description="'confirm': the reply asks 'Did you say …?'; say yes or no next"
    )


async def _read_body(request: Request) -> bytes:
    size = request.headers.get("content-length")
    if size is not None and size.isdigit() and int(size) > MAX_BODY_BYTES:
        raise HTTPException(413, f"audio body over {MAX_BODY_BYTES} bytes (at most 30 s)")
    chunks: list[bytes] = []
    total = 0
    async for chunk in request.stream():
        total += len(chunk)
        if total > MAX_BODY_BYTES:
            raise HTTPException(413, f"audio body over {MAX_BODY_BYTES} bytes (at most 30 s)")
        chunks.append(chunk)
    return b"".join(chunks)


def _service(runtime: Any) -> SpeechService:
    service: SpeechService | None = getattr(runtime, "speech", None)
    if service is None:
        raise HTTPException(503, "speech recognition is not part of this server")
    return service


@router.post(
    "/speech",
    response_model=SpeechResponse,
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {"audio/wav": {"schema": {"type": "string", "format": "binary"}}},
        }
    },
)
async def speech(
    request: Request,
    runtime: RuntimeDep,
    role: RoleDep,
    execute: Annotated[bool, Query(description="false: only transcribe")] = True,
    drone: Annotated[str | None, Query(max_length=64)] = None,
) -> SpeechResponse:
    """Recognise a spoken command (16-bit PCM WAV, any rate, mono or stereo, at most 30 s) and,
    unless ``execute=false``, run it like ``POST /command`` with its confidence.

    400 not a usable WAV / no samples, 413 too long, 415 not ``audio/wav``, 403 an observer
    asking to execute, 409 another pilot holds the lease, 503 busy (Retry-After), no model, or
    the drone's flight process starting, gone or silent (Retry-After; ``server.vehicles``).
    """
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype not in WAV_TYPES:
        raise HTTPException(415, f"Content-Type must be audio/wav, not {ctype or 'missing'!r}")
    if execute and role != Role.PILOT:
        raise HTTPException(403, f"role '{role}' may not command the drones (use execute=false)")
    name = drone or runtime.default_drone
    dialog = runtime.dialogs.get(name)
    if execute and dialog is None:
        raise HTTPException(404, f"no drone '{name}'")
    service = _service(runtime)
    body = await _read_body(request)
    try:
        rec = await service.recognize_wav(body)
    except AudioTooLong as exc:
        raise HTTPException(413, str(exc)) from exc
    except AudioError as exc:
        raise HTTPException(400, str(exc)) from exc
    except Busy as exc:
        raise HTTPException(503, str(exc), headers={"Retry-After": "1"}) from exc
    except ModelError as exc:
        raise HTTPException(503, f"speech recognition unavailable: {exc}") from exc
    reply, accepted, commands, expects = "", False, rec.commands, ""
    if execute and dialog is not None:
        if not rec.text:
            reply = "I heard no speech. Please repeat."
        else:
            # A "yes" names no command itself (it runs the one the dialog read back): an empty
            # set needs the lease like any command.
            check_lease(request, runtime, {c["action"] for c in rec.commands})
            runtime.note_utterance(rec.text, source="speech", confidence=rec.confidence, drone=name)
            result = await dialog.handle_utterance(
                rec.text, confidence=rec.confidence, source="speech", role=role
            )
            # As POST /command: the dialog's commands ("Yes." runs the take-off it asked about).
            reply, accepted, commands = result.reply, result.accepted, result.commands
            expects = result.expects
    return SpeechResponse(
        text=rec.text,
        confidence=round(rec.confidence, 4),
        commands=commands,
        reply=reply,
        accepted=accepted,
        heard=rec.heard,
        decode_ms=round(rec.decode_ms, 1),
        expects=expects,
    )


@router.get("/speech/status", response_model=SpeechStatus)
def speech_status(runtime: RuntimeDep, _role: RoleDep) -> SpeechStatus:
    """Whether server recognition is ready, the model, the recogniser setting, the pool load."""
    service = _service(runtime)
    running, waiting = service.pool.load if service.pool else (0, 0)
    return SpeechStatus(
        status=service.status(),
        model=service.model_name,
        recognizer=getattr(runtime.settings, "recognizer", "auto"),
        workers=service.workers,
        running=running,
        waiting=waiting,
        streams=service.streams,
    )


@router.websocket("/speech/stream")
async def speech_stream(websocket: WebSocket) -> None:
    """The browser microphone: binary frames of 16 kHz mono s16le PCM; text frames
    ``{"type": "end"}`` (push-to-talk released) and ``{"type": "cancel"}``.

    Query: ``token``, ``mode`` (ptt | handsfree), ``lease`` (the holding's secret key,
    as ``/console/lease`` tells its holder and REST callers name in ``X-Pilot-Lease``),
    ``rate`` (must be 16000). Sends ``{"type": "ready"}``, ``{"type": "interim", "text"}``,
    ``{"type": "final", text, confidence, commands, heard, doubt}``, ``{"type": "error", "error"}``.
    """
    runtime = websocket.app.state.runtime
    security = runtime.security
    q = websocket.query_params
    if not security.origin_allowed(websocket.headers.get("origin"), websocket.headers.get("host")):
        await _refuse(websocket, CLOSE_POLICY, "Origin not allowed")
        return
    role = security.role_for(token_from(websocket.headers, q))
    if role is None:
        await _refuse(websocket, CLOSE_POLICY, "a valid token is required")
        return
    if role != Role.PILOT:
        await _refuse(websocket, CLOSE_POLICY, f"role '{role}' may not speak commands")
        return
    # The same credential REST checks (holder ids are secret, the key is what the
    # holder is told); a pilot without it may not speak while another holds the lease.
    lease = security.lease
    if lease.state.holder is not None and not lease.key_matches(q.get("lease")):
        await _refuse(
            websocket, CLOSE_POLICY, "another pilot holds the pilot lease; take over to speak"
        )
        return
    mode = q.get("mode", "ptt")
    if mode not in MODES or q.get("rate", "16000") != "16000":
        await _refuse(websocket, CLOSE_POLICY, "mode must be ptt or handsfree and rate 16000")
        return
    service: SpeechService | None = getattr(runtime, "speech", None)
    if service is None:
        await _refuse(websocket, CLOSE_TRY_AGAIN, "speech recognition is not part of this server")
        return
    if service.streams >= service.config.max_streams:
        await _refuse(websocket, CLOSE_TRY_AGAIN, "too many microphone streams; try again later")
        return
    service.streams += 1
    lift_frame_cap(websocket.scope)  # a pilot: audio frames may exceed the pre-auth 4 KB
    try:
        await websocket.accept()
        await _Stream(websocket, service, mode).run()
    finally:
        service.streams -= 1


def _timed(fn: Callable[[], T]) -> tuple[T, float, float, float]:
    """``fn()`` on the calling thread: (its result, wall start and end in epoch seconds, the
    process's CPU seconds meanwhile: CTranslate2 computes on threads of its own, so the CPU a
    decode costs is the process's, which includes whatever else ran in it then)."""
    t0, c0 = time.time(), time.process_time()
    out = fn()
    return out, t0, time.time(), time.process_time() - c0


async def _refuse(websocket: WebSocket, code: int, reason: str) -> None:
    """Accept, then close with ``code`` and ``reason``: a browser sees a close reason, never
    the body of a refused handshake, and the page shows the operator why."""
    with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
        await websocket.accept()
        await websocket.close(code, reason)


class _Stream:
    """One accepted stream: reads frames, runs decodes, sends text (a thin asyncio shell
    around :class:`StreamSession`)."""

    def __init__(self, ws: WebSocket, service: SpeechService, mode: str) -> None:
        self.ws = ws
        self.service = service
        self.mode = mode
        # Both modes end-point with the voice detector, to decode speculatively
        # (server.speech.stream); hands-free also ends utterances with it.
        step = PTT_INTERIM_S if mode == "ptt" else HANDSFREE_INTERIM_S
        self.session = StreamSession(mode, score=SileroStream(), interim_step_s=step)
        self._interim: asyncio.Task[None] | None = None
        self._speculations: set[asyncio.Task[None]] = set()
        self._finals: asyncio.Queue[tuple[Final, dict[str, float]] | None] = asyncio.Queue(
            maxsize=2
        )
        self._vad_lock = asyncio.Lock()
        # When each stage of the utterance under way happened (epoch seconds) and the CPU it
        # cost (ms): sent with its final as ``timing`` (bench/speech_latency.py's breakdown).
        self._t: dict[str, float] = {}

    async def run(self) -> None:
        try:
            await self.service.ready()
        except ModelError as exc:
            await self._send({"type": "error", "error": f"speech recognition unavailable: {exc}"})
            await self.ws.close(CLOSE_TRY_AGAIN, "speech recognition unavailable")
            return
        await self._send({"type": "ready", "mode": self.mode, "model": self.service.model_name})
        finals = asyncio.create_task(self._decode_finals())
        try:
            await self._read()
        finally:
            with contextlib.suppress(asyncio.QueueFull):
                self._finals.put_nowait(None)
            if self._interim is not None:
                self._interim.cancel()
            for task in list(self._speculations):
                task.cancel()
            with contextlib.suppress(asyncio.TimeoutError, Exception):
                await asyncio.wait_for(finals, 35.0)
            finals.cancel()

    async def _receive(self, inbox: asyncio.Queue[dict[str, Any]]) -> None:
        """Frames off the socket into ``inbox`` (bounded: a full inbox holds the socket back),
        ending with a disconnect, however the socket ended."""
        try:
            while (msg := await self.ws.receive())["type"] != "websocket.disconnect":
                await inbox.put({**msg, "at": time.time()})
        finally:
            with contextlib.suppress(asyncio.QueueFull):
                inbox.put_nowait({"type": "websocket.disconnect"})

    async def _read(self) -> None:
        """Handle frames in order; audio frames that queued up while the previous ones were
        handled (a busy machine) go to the session in one batch, one voice-detector call."""
        inbox: asyncio.Queue[dict[str, Any]] = asyncio.Queue(maxsize=INBOX_FRAMES)
        receiver = asyncio.create_task(self._receive(inbox))
        try:
            await self._handle_frames(inbox, receiver)
        finally:
            receiver.cancel()

    async def _handle_frames(
        self, inbox: asyncio.Queue[dict[str, Any]], receiver: asyncio.Task[None]
    ) -> None:
        pending: collections.deque[dict[str, Any]] = collections.deque()
        while True:
            if not pending:
                try:
                    pending.append(await asyncio.wait_for(inbox.get(), STREAM_IDLE_S))
                except TimeoutError:
                    pending.append({"type": "idle"})
            while not inbox.empty():
                pending.append(inbox.get_nowait())
            msg = pending.popleft()
            if msg["type"] == "idle" and receiver.done() and inbox.empty():
                return  # the socket is gone (its disconnect did not fit in a full inbox)
            if msg["type"] == "idle":
                if self.session.buffered_s > 0 and self.mode == "ptt":
                    async with self._vad_lock:
                        self.session.cancel()
                    await self._send(
                        {"type": "error", "error": "no audio for 10 s: utterance discarded"}
                    )
                continue
            if msg["type"] == "websocket.disconnect":
                return
            data: bytes | None = msg.get("bytes")
            text: str | None = msg.get("text")
            if data is not None:
                audio = [data]
                while pending and pending[0].get("bytes") is not None:
                    audio.append(pending.popleft()["bytes"])
                if any(len(d) > MAX_FRAME_BYTES for d in audio):
                    await self._send({"type": "error", "error": "audio frame over 64 KiB"})
                    await self.ws.close(CLOSE_POLICY, "audio frame too large")
                    return
                # Whole samples per frame: a frame of odd length loses its last byte, as alone.
                pcm = b"".join(d[: len(d) - len(d) % 2] for d in audio)
                async with self._vad_lock:  # the session runs the VAD: off the event loop
                    silent = self.session.in_silence
                    events, cpu = await asyncio.to_thread(self._feed, pcm)
                    if self.session.in_silence and not silent:
                        # The voice detector heard the speech end in this batch of frames.
                        self._t["silence_heard"] = float(msg.get("at") or time.time())
                        self._t["silence_scored"] = time.time()
                # The VAD's CPU since the last final, and the 32 ms frames it scored meanwhile.
                self._t["vad_cpu_ms"] = self._t.get("vad_cpu_ms", 0.0) + cpu * 1000
                self._t["vad_frames"] = self._t.get("vad_frames", 0.0) + len(pcm) / 1024
            elif text is not None:
                kind = control_kind(text)
                if kind == "end":
                    async with self._vad_lock:
                        events = self.session.end()
                    if not events:
                        await self._send(
                            {
                                "type": "final",
                                "text": "",
                                "confidence": 0.0,
                                "commands": [],
                                "heard": "",
                            }
                        )
                elif kind == "cancel":
                    async with self._vad_lock:
                        self.session.cancel()
                    events = []
                else:
                    await self._send({"type": "error", "error": "text frames: end or cancel"})
                    events = []
            else:
                events = []
            for ev in events:
                await self._handle(ev)

    def _feed(self, pcm: bytes) -> tuple[list[Event], float]:
        """The session's events for ``pcm`` and the thread CPU seconds they cost (the VAD)."""
        c0 = time.thread_time()
        events = self.session.feed(pcm)
        return events, time.thread_time() - c0

    async def _handle(self, ev: Event) -> None:
        if isinstance(ev, Problem):
            await self._send({"type": "error", "error": ev.message})
        elif isinstance(ev, Speculation):
            task = asyncio.create_task(self._speculate(ev))
            self._speculations.add(task)
            task.add_done_callback(self._speculations.discard)
        elif isinstance(ev, Interim):
            # Interim text is a nicety: never while a speculation (the likely final) waits.
            idle = not self._speculations and (self._interim is None or self._interim.done())
            if idle:
                self._interim = asyncio.create_task(self._decode_interim(ev.samples.copy()))
        else:
            if self._interim is not None:
                self._interim.cancel()
            timing, self._t = {**self._t, "final": time.time()}, {}
            try:
                self._finals.put_nowait((ev, timing))
            except asyncio.QueueFull:
                await self._send(
                    {"type": "error", "error": "still decoding the previous utterances: dropped"}
                )

    async def _decode_interim(self, samples: Samples) -> None:
        """A whole recognition (VAD, decode, snap), not only a transcript, for interim text."""
        assert self.service.pool is not None and self.service.recognizer is not None
        rec = self.service.recognizer
        out = await self.service.pool.try_run(rec.recognize, samples)
        if out is not None and out.heard:
            await self._send({"type": "interim", "text": out.heard})

    async def _speculate(self, ev: Speculation) -> None:
        """Decode the speech while the operator may still go on; the session ends the
        utterance early on a decisive reading. The final of the same speech reuses this
        decode (server.speech.memo), waiting for it if it is still running."""
        assert self.service.pool is not None and self.service.recognizer is not None
        recognizer = self.service.recognizer
        asked = time.time()
        decode = functools.partial(recognizer.recognize, ev.samples, vad=False)
        try:
            rec, t0, t1, cpu = await self.service.pool.run(_timed, decode)
        except Busy:
            return  # the final decodes it in its turn
        self._t.update(spec_asked=asked, spec_start=t0, spec_end=t1, spec_cpu_ms=cpu * 1000)
        sure = decisive(rec, self.service.nlu, self.service.config.threshold)
        async with self._vad_lock:
            events = self.session.decided(ev.serial, sure)
        if rec.heard and not events:
            await self._send({"type": "interim", "text": rec.heard})
        for out in events:
            await self._handle(out)

    async def _decode_finals(self) -> None:
        while (item := await self._finals.get()) is not None:
            final, timing = item
            samples = final.samples
            t0, c0 = time.time(), time.process_time()
            try:
                rec: Recognition = await self.service.recognize(samples, vad=not final.trimmed)
            except Busy as exc:
                await self._send({"type": "error", "error": str(exc)})
                continue
            except ModelError as exc:
                await self._send({"type": "error", "error": str(exc)})
                continue
            timing.update(
                decode_start=t0,
                decode_end=time.time(),
                decode_cpu_ms=(time.process_time() - c0) * 1000,
                reused=float(rec.reused),
            )
            msg: dict[str, Any] = {"type": "final", **rec.as_json()}
            log.info(
                "speech final %r (heard %r, confidence %.2f) from %.1f s of audio%s",
                msg.get("text"), msg.get("heard"), float(msg.get("confidence") or 0.0),
                len(samples) / SAMPLE_RATE, " (reused)" if rec.reused else "",
            )  # fmt: skip
            timing["sent"] = time.time()
            msg["timing"] = {k: round(v, 4) for k, v in timing.items()}
            await self._send(msg)

    async def _send(self, msg: dict[str, Any]) -> None:
        with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
            await self.ws.send_text(json.dumps(msg))
