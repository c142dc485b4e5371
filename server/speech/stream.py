"""One browser microphone stream, sans-I/O: PCM bytes in, decode requests out.

The browser sends 16 kHz mono 16-bit PCM in binary frames (an AudioWorklet resamples the
microphone). Two modes:

* ``ptt`` (push-to-talk): audio accumulates while the button or key is held; ``end()`` on
  release gives the :class:`Final` utterance. While it grows, an :class:`Interim` request is
  emitted every ``interim_step_s`` of new audio (the wrapper decodes it only when a decoder is
  idle, so interim text never delays a final one).
* ``handsfree``: voice activity detection (Silero VAD, shipped with faster-whisper, injected as
  ``detect``) on the recent audio finds where speech starts; ``end_silence_s`` of silence after
  it ends the utterance. Audio before any speech is dropped, so an open microphone in a quiet
  room holds at most ``keep_s`` of samples.

Both modes also decode speculatively: when ``detect`` (if given) hears the last
``settle_s`` of audio fall silent after speech, an :class:`Interim` is emitted at once. The
speech it carries is, most often, exactly the speech of the :class:`Final` that follows (the
release a moment later, or hands-free's ``end_silence_s``), and the recogniser then reuses that
decode instead of starting over (:mod:`server.speech.memo`).

Memory is bounded in both modes: an utterance longer than ``max_utterance_s`` is refused
(push-to-talk) or cut there (hands-free), never buffered further.

Text frames carry control messages only, ``{"type": "end"}`` and ``{"type": "cancel"}``
(:func:`control_kind`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from server.speech.audio import SAMPLE_RATE, Samples, pcm16_to_float

Detect = Callable[[Samples], bool]  # does this stretch of audio hold speech?
MODES = ("ptt", "handsfree")


@dataclass(frozen=True)
class Interim:
    samples: Samples


@dataclass(frozen=True)
class Final:
    samples: Samples


@dataclass(frozen=True)
class Problem:
    message: str


Event = Interim | Final | Problem


def control_kind(text: str) -> str | None:
    """The ``type`` of one text frame of the stream, or None for anything that is not a JSON
    object with a string ``type`` (never raises: not JSON, a list, a document nested deeper
    than the interpreter's stack, which ``json`` reports as RecursionError)."""
    try:
        value = json.loads(text)
    except (ValueError, RecursionError):
        return None
    kind = value.get("type") if isinstance(value, dict) else None
    return kind if isinstance(kind, str) else None


class StreamSession:
    """Feed PCM with :meth:`feed`; release with :meth:`end`; both return events in order."""

    def __init__(
        self,
        mode: str,
        *,
        detect: Detect | None = None,
        max_utterance_s: float = 30.0,
        interim_step_s: float = 0.8,
        end_silence_s: float = 0.7,
        vad_window_s: float = 0.5,
        keep_s: float = 1.0,
        settle_s: float = 0.35,
        settle_step_s: float = 0.1,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, not {mode!r}")
        if mode == "handsfree" and detect is None:
            raise ValueError("hands-free mode needs a voice activity detector")
        self.mode = mode
        self.detect = detect
        self.max_samples = int(max_utterance_s * SAMPLE_RATE)
        self.interim_step = int(interim_step_s * SAMPLE_RATE)
        self.end_silence = int(end_silence_s * SAMPLE_RATE)
        self.vad_window = int(vad_window_s * SAMPLE_RATE)
        self.keep = int(keep_s * SAMPLE_RATE)
        # > the recogniser's VAD pad (0.3 s), so the speculative decode trims to the same speech
        self.settle = int(settle_s * SAMPLE_RATE)
        self.settle_step = int(settle_step_s * SAMPLE_RATE)  # how often the tail is checked
        self._since_settle = 0
        self._buf = np.zeros(0, np.float32)
        self._since_interim = 0
        self._since_vad = 0
        self._overflow = False
        self._speaking = False
        self._silent = 0  # samples of silence since the last speech (hands-free)
        self._heard = False  # speech heard since the last speculative decode
        self.speculated = 0  # speculative decodes asked for (tests, logs)
        self.utterances = 0

    @property
    def buffered_s(self) -> float:
        return len(self._buf) / SAMPLE_RATE

    def feed(self, pcm: bytes) -> list[Event]:
        """Add little-endian 16-bit mono PCM at 16 kHz."""
        chunk = pcm16_to_float(pcm)
        if chunk.size == 0:
            return []
        if self.mode == "ptt":
            return self._feed_ptt(chunk)
        return self._feed_handsfree(chunk)

    def _feed_ptt(self, chunk: Samples) -> list[Event]:
        if self._overflow:
            return []
        if len(self._buf) + len(chunk) > self.max_samples:
            self._overflow = True
            self._buf = np.zeros(0, np.float32)
            seconds = self.max_samples / SAMPLE_RATE
            return [Problem(f"longer than {seconds:.0f} s: this utterance is discarded")]
        self._buf = np.concatenate([self._buf, chunk])
        self._since_interim += len(chunk)
        if (speculation := self._settled(len(chunk))) is not None:
            return [speculation]
        if self._since_interim >= self.interim_step:
            self._since_interim = 0
            return [Interim(self._buf)]
        return []

    def _settled(self, added: int) -> Interim | None:
        """Every ``settle_step`` of audio: the speculative :class:`Interim` if the last
        ``settle`` of audio is silent after speech was heard, else None."""
        self._since_settle += added
        if self.detect is None or self._since_settle < self.settle_step:
            return None
        self._since_settle = 0
        if self.detect(self._buf[-self.settle :]):
            self._heard = True
            return None
        if not self._heard:
            return None
        self._heard = False  # speech, then silence: the utterance is likely complete
        self._since_interim = 0
        self.speculated += 1
        return Interim(self._buf)

    def _feed_handsfree(self, chunk: Samples) -> list[Event]:
        assert self.detect is not None
        self._buf = np.concatenate([self._buf, chunk])
        self._since_vad += len(chunk)
        events: list[Event] = []
        if self._speaking and (speculation := self._settled(len(chunk))) is not None:
            events.append(speculation)
        if self._since_vad < self.vad_window // 2:
            return events
        self._since_vad = 0
        voiced = self.detect(self._buf[-self.vad_window :])
        if not self._speaking:
            if voiced:
                self._speaking, self._silent, self._since_interim = True, 0, 0
                self._heard = True
            else:
                self._buf = self._buf[-self.keep :]  # pre-roll: the start of the first word
            return events
        # A silent window means at least a window's worth of silence.
        step = self.vad_window // 2
        self._silent = 0 if voiced else (self._silent + step if self._silent else self.vad_window)
        self._since_interim += step
        if self._silent >= self.end_silence or len(self._buf) >= self.max_samples:
            events.append(Final(self._buf[: self.max_samples]))
            self.utterances += 1
            self._buf = np.zeros(0, np.float32)
            self._speaking = False
            return events
        if self._since_interim >= self.interim_step:
            self._since_interim = 0
            events.append(Interim(self._buf))
        return events

    def end(self) -> list[Event]:
        """Push-to-talk released (or hands-free stopped): the utterance so far, if any."""
        buf, overflow, speaking = self._buf, self._overflow, self._speaking
        self.cancel()
        if overflow or buf.size == 0:
            return []
        if self.mode == "handsfree" and not speaking:
            return []
        self.utterances += 1
        return [Final(buf)]

    def cancel(self) -> None:
        """Drop whatever was heard."""
        self._buf = np.zeros(0, np.float32)
        self._since_interim = self._since_vad = self._silent = self._since_settle = 0
        self._overflow = self._speaking = self._heard = False
