"""The speech service of one server: the model (loaded in the background at start), the
decoder pool and the entry points the REST route, the stream route and the CLI use."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from server.language.nlu import NLU
from server.speech import model as model_mod
from server.speech import window
from server.speech.audio import Samples, read_wav
from server.speech.errors import ModelError, SpeechError
from server.speech.gaps import GapLog
from server.speech.pool import DecoderPool
from server.speech.recognizer import BEAMS, THRESHOLD, Recognition, Recognizer

log = logging.getLogger("uav_console.speech")
# Words after which a sentence goes on: a reading ending on one is not decisive (decisive).
CONTINUING = frozenset(
    {"and", "then", "to", "by", "at", "of", "the", "a", "an", "for", "from", "with", "or"}
    | {"but", "marker", "waypoint", "point"}
)


@dataclass(frozen=True)
class SpeechConfig:
    """The speech settings (from :class:`server.settings.Settings`)."""

    model_dir: Path | None = None  # None: the bundled tiny.en
    model_sha256: str | None = None
    workers: int = 0  # 0: model.default_workers()
    threads_per_worker: int = 1
    queue: int = 4  # requests that may wait for a decoder before Busy
    max_streams: int = 8  # browser streams open at once
    window_s: float = 0.0  # shortest encoder window; 0: the recogniser's (server.speech.window)
    beams: int = 0  # 0: the recogniser's (server.speech.recognizer.BEAMS)
    threshold: float = THRESHOLD  # the dialog's confidence threshold: doubtful readings under it
    gap_log: Path | None = None  # grammar gaps (server.speech.gaps); None: not logged


def decisive(rec: Recognition, nlu: NLU, threshold: float) -> bool:
    """Whether the dialog takes ``rec`` as heard, at once: commands (or a yes/no answer) at the
    threshold or above, nothing doubting them, and nothing left open: a transcript ending on a
    word that continues a sentence ("Take off and"), or a move or turn whose distance or angle
    is unsaid ("Turn left" may be followed by "ninety degrees"). The stream ends an utterance
    early on a decisive reading (:mod:`server.speech.stream`), else after its full silence."""
    if rec.confidence < threshold or rec.doubt:
        return False
    words = rec.heard.lower().replace(",", " ").replace(".", " ").split()
    if not words or words[-1] in CONTINUING:
        return False
    if not rec.commands:
        return nlu.answer(rec.text) is not None
    last = rec.commands[-1]
    return not (
        (last.get("action") == "move" and "distance" not in last)
        or (last.get("action") == "turn" and "angle" not in last)
    )


class SpeechService:
    """Loads the recogniser once and runs recognitions on a bounded pool."""

    def __init__(
        self, config: SpeechConfig, nlu: NLU, clock: Callable[[], float] = time.time
    ) -> None:
        self.config = config
        self.nlu = nlu
        self.clock = clock
        self.gaps = GapLog(config.gap_log) if config.gap_log is not None else None
        self.workers = config.workers or model_mod.default_workers()
        self.pool: DecoderPool | None = None
        self.recognizer: Recognizer | None = None
        self.error: SpeechError | None = None
        self.model_name = ""
        self._loading: asyncio.Task[None] | None = None
        self.streams = 0  # open browser streams

    def load(self) -> Recognizer:
        """Load synchronously (the CLI; the server calls :meth:`start`).

        Raises:
            ModelError: the model is missing, damaged or unloadable.
        """
        source = model_mod.resolve(self.config.model_dir, self.config.model_sha256)
        self.model_name = source.name
        whisper = model_mod.load_whisper(
            source, workers=self.workers, threads_per_worker=self.config.threads_per_worker
        )
        recognizer = Recognizer(
            whisper,
            self.nlu,
            window_s=self.config.window_s or window.MIN_S,
            beams=self.config.beams or BEAMS,
            threshold=self.config.threshold,
        )
        recognizer.warm_up()  # ready means warm: the first command pays no first-decode cost
        self.recognizer = recognizer
        return recognizer

    async def start(self, *, preload: bool = True) -> None:
        """Create the pool; with ``preload`` load the model now, in a thread (start-up is not
        delayed by it), else on first use (an app built for a test that never speaks does
        not pay the ~1 s of CPU a load costs)."""
        self.pool = DecoderPool(self.workers, self.config.queue)
        if preload:
            self._begin_loading()

    def _begin_loading(self) -> None:
        if self._loading is None:
            self._loading = asyncio.create_task(self._load(), name="speech-model")

    async def _load(self) -> None:
        try:
            await asyncio.to_thread(self.load)
            log.info("speech recognition ready (%s, %d decoders)", self.model_name, self.workers)
        except ModelError as exc:
            self.error = exc
            log.warning("speech recognition unavailable: %s", exc)

    async def ready(self) -> Recognizer:
        """The recogniser, once loaded.

        Raises:
            ModelError: loading failed (the reason is in the message).
        """
        if self._loading is None and self.pool is not None:
            self._begin_loading()
        if self._loading is not None:
            await asyncio.shield(self._loading)
        if self.error is not None:
            raise self.error
        if self.recognizer is None:
            raise ModelError("speech recognition was not started")
        return self.recognizer

    def status(self) -> str:
        """'ready', 'loading', or why speech recognition is unavailable."""
        if self.error is not None:
            return f"unavailable: {self.error}"
        if self.recognizer is None:
            return "loading" if self._loading is not None else "loads on first use"
        return "ready"

    async def recognize(
        self,
        samples: Samples,
        *,
        guided: bool = True,
        state: str | None = None,
        vad: bool = True,
    ) -> Recognition:
        """Recognise 16 kHz samples on the pool (a whole utterance: its grammar gap, if any, is
        logged; the stream's speculative decodes are not). ``vad=False``: the samples are the
        speech already (the stream's end-pointer trimmed them).

        Raises:
            ModelError: no model; Busy: the pool is full.
        """
        recognizer = await self.ready()
        assert self.pool is not None
        rec = await self.pool.run(
            recognizer.recognize, samples, guided=guided, state=state, vad=vad
        )
        if rec.gap and self.gaps is not None:
            await asyncio.to_thread(self.gaps.record, rec, self.clock())
        return rec

    async def recognize_wav(self, data: bytes, *, state: str | None = None) -> Recognition:
        """Decode a WAV file (raises AudioError subclasses) and recognise it."""
        samples = await asyncio.to_thread(read_wav, data)
        return await self.recognize(samples, state=state)

    async def stop(self) -> None:
        if self._loading is not None and not self._loading.done():
            self._loading.cancel()
        if self.pool is not None:
            self.pool.close()
