"""One browser microphone stream, sans-I/O: PCM bytes in, decode requests out.

The browser sends 16 kHz mono 16-bit PCM in binary frames (an AudioWorklet resamples the
microphone; 32 ms frames, one voice-detector frame each). Two modes:

* ``ptt`` (push-to-talk): audio accumulates while the button or key is held; ``end()`` on
  release gives the :class:`Final` utterance. While it grows, an :class:`Interim` request is
  emitted every ``interim_step_s`` of new audio (the wrapper decodes it only when a decoder is
  idle, so interim text never delays a final one).
* ``handsfree``: the voice detector finds where speech starts and ends; audio before any speech
  is dropped (an open microphone in a quiet room holds at most ``keep_s`` of samples).

**End-pointing.** Each 512-sample frame is scored once by ``score`` (Silero VAD's speech
probability, injected; the frames that arrived since the last call in one batch, so a server
that fell behind catches up), with Silero's own hysteresis (speech from ``threshold``, silence under
``neg_threshold``: faster-whisper ``get_speech_timestamps``). When ``settle_s`` of silence
follows speech, the session asks for a :class:`Speculation`: the speech only (``pre_s``
before its first voiced frame, ``settle_s`` after its last), decoded while the operator may
still go on. The wrapper tells the result (:meth:`StreamSession.decided`):

* hands-free, a **decisive** reading (one the dialog flies as heard) ends the utterance as soon
  as ``commit_s`` of silence has passed and the silence lasted through the decode: the
  :class:`Final` carries the speculation's samples, so the recogniser reuses its result
  (:mod:`server.speech.memo`). Otherwise the utterance ends after ``end_silence_s`` of silence,
  with the same samples (and the same reuse);
* speech that resumes voids the speculation (the operator paused mid-sentence);
* push-to-talk ends on release only; the final reuses the speculation when no speech followed.

**Speculating early.** The decode is the longest stage from the end of speech to the command,
so the speculation is asked once ``listen_s`` of silence is heard, not ``settle_s``: the part
of the ``settle_s`` pad not heard yet is the silence heard so far, repeated (the pad exists for
a soft last sound Silero scores as silence; those lie within ``listen_s`` of its end on the
spoken sets: :data:`LISTEN_S`). When the whole pad has been heard and it is louder than the
silence that stood in for it (a sound after all), the speculation is asked again with the pad
as heard, voiding the first.

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

# Speech probability of each 512-sample frame of the samples given: the stream's next frames,
# in order (a recurrent scorer keeps its state between calls: recognizer.SileroStream).
Score = Callable[[Samples], np.ndarray]
MODES = ("ptt", "handsfree")
FRAME = 512  # Silero VAD's window at 16 kHz (faster_whisper.vad: window_size_samples)
THRESHOLD = 0.5  # Silero's speech threshold (faster_whisper.vad.VadOptions.threshold)
NEG_THRESHOLD = THRESHOLD - 0.15  # its silence threshold (get_speech_timestamps' default)
# Silence heard before the speculative decode starts: 4 frames (128 ms). On bench/speech.py's
# clean clips (36 utterances x 3 speeds each) the last audible sample (-60 dBFS) lies after the
# start of the first frame Silero scores as silence by at most 36 ms for hibari-tts's commands
# (128 ms for a lone "the"), 90 ms for espeak-ng's voices and 177 ms for flite's (p90 131 ms):
# a later sound is caught by the pad's check (LOUDER) and decoded again as heard.
LISTEN_S = 4 * FRAME / SAMPLE_RATE
# A pad heard louder than this many times the silence that stood in for it (RMS) is a sound
# after all, and so is anything above -60 dBFS RMS after digital silence (the end-of-speech
# threshold of bench/speech_latency.py).
LOUDER = 2.0
SILENT_RMS = 2.0**-10


@dataclass(frozen=True)
class Interim:
    """Audio to decode for interim text only, while the operator speaks."""

    samples: Samples


@dataclass(frozen=True)
class Speculation:
    """The speech of the utterance so far, which may be all of it: decode it now, and tell
    the session whether the reading is decisive (:meth:`StreamSession.decided`)."""

    samples: Samples
    serial: int


@dataclass(frozen=True)
class Final:
    """The utterance. ``trimmed``: the samples are the speech already (the recogniser skips its
    own voice detection, and a speculation of the same samples is reused)."""

    samples: Samples
    trimmed: bool = False


@dataclass(frozen=True)
class Problem:
    message: str


Event = Interim | Speculation | Final | Problem


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
    """Feed PCM with :meth:`feed`; release with :meth:`end`; tell speculative readings with
    :meth:`decided`; each returns events in order."""

    def __init__(
        self,
        mode: str,
        *,
        score: Score | None = None,
        max_utterance_s: float = 30.0,
        interim_step_s: float = 0.8,
        end_silence_s: float = 0.7,
        keep_s: float = 1.0,
        pre_s: float = 0.3,
        settle_s: float = 0.3,
        commit_s: float = 0.3,
        listen_s: float = LISTEN_S,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, not {mode!r}")
        if mode == "handsfree" and score is None:
            raise ValueError("hands-free mode needs a voice activity detector")
        if not 0 < listen_s <= settle_s <= commit_s <= end_silence_s:
            raise ValueError("need 0 < listen_s <= settle_s <= commit_s <= end_silence_s")
        self.mode = mode
        self.score = score
        self.max_samples = int(max_utterance_s * SAMPLE_RATE)
        self.interim_step = int(interim_step_s * SAMPLE_RATE)
        self.end_silence = int(end_silence_s * SAMPLE_RATE)
        self.keep = max(int(keep_s * SAMPLE_RATE), int(pre_s * SAMPLE_RATE) + FRAME)
        self.pre = int(pre_s * SAMPLE_RATE)
        # The speculation keeps settle_s of silence after the speech: Silero ends speech at the
        # first quiet frame, and a soft last consonant may lie after it. 0.3 s is the pad the
        # recogniser's own trim gives a whole clip (recognizer.VAD_PAD_S), the speech the
        # doubt rules were chosen on: with 0.2 s, 3 of bench/speech.py's 324 espeak-ng clips
        # are flown wrong (a beam's doubt does not show).
        self.settle = int(settle_s * SAMPLE_RATE)
        self.listen = int(listen_s * SAMPLE_RATE)
        self.commit = int(commit_s * SAMPLE_RATE)
        self.speculated = 0  # speculative decodes asked for (tests, logs)
        self.committed = 0  # utterances ended early on a decisive reading (tests, logs)
        self.utterances = 0
        self._serial = 0
        self._buf: Samples = np.zeros(0, np.float32)
        self._scored = 0  # samples of _buf the detector has scored
        self._start: int | None = None  # where the utterance's audio starts (pre-roll in)
        self._quiet_from: int | None = None  # where the silence after the speech began
        self._spec: Samples | None = None  # the current speculation's samples
        self._spec_heard = False  # its settle_s pad was heard whole (not partly repeated)
        self._spec_serial = 0
        self._decisive = False
        self._since_interim = 0
        self._overflow = False

    @property
    def buffered_s(self) -> float:
        return len(self._buf) / SAMPLE_RATE

    @property
    def in_silence(self) -> bool:
        """Speech was heard and the voice detector has heard only silence since (the end-pointer
        is waiting to end the utterance)."""
        return self._start is not None and self._quiet_from is not None

    def feed(self, pcm: bytes) -> list[Event]:
        """Add little-endian 16-bit mono PCM at 16 kHz."""
        chunk = pcm16_to_float(pcm)
        if chunk.size == 0 or self._overflow:
            return []
        if self.mode == "ptt" and len(self._buf) + len(chunk) > self.max_samples:
            self._overflow = True
            self._buf = np.zeros(0, np.float32)
            seconds = self.max_samples / SAMPLE_RATE
            return [Problem(f"longer than {seconds:.0f} s: this utterance is discarded")]
        self._buf = np.concatenate([self._buf, chunk])
        events: list[Event] = []
        if self.score is not None and self._scored + FRAME <= len(self._buf):
            n = (len(self._buf) - self._scored) // FRAME
            probs = np.ravel(self.score(self._buf[self._scored : self._scored + n * FRAME]))
            for prob in probs[:n]:
                events += self._frame(float(prob))
        if self.mode == "ptt":
            self._since_interim += len(chunk)
            if self._since_interim >= self.interim_step and not events:
                self._since_interim = 0
                events.append(Interim(self._buf))
        elif self._start is None and self._scored >= self.keep + FRAME:
            # Pre-roll only (the start of the first word); whole frames, so that frames stay
            # where they were in the stream, whatever was dropped.
            drop = (self._scored - self.keep) // FRAME * FRAME
            self._buf, self._scored = self._buf[drop:], self._scored - drop
        return events

    def _frame(self, prob: float) -> list[Event]:
        """The next frame's speech probability moves the end-pointer (Silero's hysteresis)."""
        at = self._scored
        self._scored += FRAME
        if self._start is None:
            if prob < THRESHOLD:
                return []
            self._start, self._quiet_from, self._since_interim = max(0, at - self.pre), None, 0
            return []
        if prob >= THRESHOLD:
            if self._quiet_from is not None:  # spoke again: the speculation was premature
                self._quiet_from, self._spec, self._decisive = None, None, False
                self._spec_heard = False
            return self._interim_while_speaking()
        if prob >= NEG_THRESHOLD:
            return [] if self._quiet_from is not None else self._interim_while_speaking()
        if self._quiet_from is None:
            self._quiet_from = at
        return self._after_silence()

    def _interim_while_speaking(self) -> list[Event]:
        if self.mode != "handsfree":
            return []
        self._since_interim += FRAME
        if self._start is not None and self._scored - self._start >= self.max_samples:
            cut = self._buf[self._start : self._start + self.max_samples]
            return self._final(cut, trimmed=True)
        if self._since_interim < self.interim_step:
            return []
        self._since_interim = 0
        return [Interim(self._buf[self._start : self._scored])]

    def _after_silence(self) -> list[Event]:
        assert self._quiet_from is not None and self._start is not None
        quiet = self._scored - self._quiet_from
        events: list[Event] = []
        if self._spec is None and quiet >= self.listen:
            heard = self._buf[self._quiet_from : self._quiet_from + self.listen]
            pad = np.resize(heard, self.settle - self.listen) if heard.size else heard
            speech = self._buf[self._start : self._quiet_from + self.listen]
            events.append(self._speculate(np.concatenate([speech, pad])))
            self._spec_heard = self.listen >= self.settle
        if self._spec is not None and not self._spec_heard and quiet >= self.settle:
            self._spec_heard = True
            heard = self._buf[self._quiet_from : self._quiet_from + self.listen]
            tail = self._buf[self._quiet_from + self.listen : self._quiet_from + self.settle]
            if _rms(tail) > max(LOUDER * _rms(heard), SILENT_RMS):
                events.append(
                    self._speculate(self._buf[self._start : self._quiet_from + self.settle])
                )
        ends = (self._decisive and quiet >= self.commit) or quiet >= self.end_silence
        if self.mode == "handsfree" and self._spec is not None and ends:
            self.committed += quiet < self.end_silence
            events += self._final(self._spec, trimmed=True)
        return events

    def _speculate(self, samples: Samples) -> Speculation:
        """A new speculation of ``samples``; an earlier one's reading is void."""
        self._serial += 1
        self._spec = samples
        self._spec_serial, self._decisive = self._serial, False
        self.speculated += 1
        return Speculation(samples, self._serial)

    def decided(self, serial: int, decisive: bool) -> list[Event]:
        """The reading of :class:`Speculation` ``serial``: decisive or not. Hands-free, a
        decisive reading of speech still followed only by silence ends the utterance once
        ``commit_s`` of silence has passed (at once, if it has)."""
        if serial != self._spec_serial or self._spec is None:
            return []  # speech resumed, or the utterance ended: stale
        self._decisive = decisive
        if self.mode != "handsfree" or not decisive or self._quiet_from is None:
            return []
        if self._scored - self._quiet_from < self.commit:
            return []
        self.committed += 1
        return self._final(self._spec, trimmed=True)

    def _final(self, samples: Samples, *, trimmed: bool) -> list[Event]:
        """Hands-free: the utterance ends; what follows it starts the next one."""
        rest = self._buf[self._scored :]
        # Pre-roll for the next utterance: the silence after this one, never its speech.
        quiet = self._scored if self._quiet_from is None else self._quiet_from
        self._reset(keep=self._buf[max(quiet, self._scored - self.keep) : self._scored])
        self._buf = np.concatenate([self._buf, rest])
        self.utterances += 1
        return [Final(samples, trimmed=trimmed)]

    def end(self) -> list[Event]:
        """Push-to-talk released (or hands-free stopped): the utterance so far, if any."""
        buf, overflow, start, spec = self._buf, self._overflow, self._start, self._spec
        quiet_from = self._quiet_from
        self.cancel()
        if overflow or buf.size == 0:
            return []
        if self.mode == "handsfree" and start is None:
            return []
        self.utterances += 1
        if spec is not None:
            return [Final(spec, trimmed=True)]  # nothing but silence followed it
        if start is None:
            return [Final(buf)]  # no voice detector, or it heard nothing: the recogniser's VAD
        stop = len(buf) if quiet_from is None else min(len(buf), quiet_from + self.settle)
        return [Final(buf[start:stop], trimmed=True)]

    def cancel(self) -> None:
        """Drop whatever was heard."""
        self._reset(keep=np.zeros(0, np.float32))
        self._overflow = False

    def _reset(self, keep: Samples) -> None:
        self._buf = keep
        self._scored = len(keep)
        self._start = self._quiet_from = None
        self._spec = None
        self._spec_heard = False
        self._spec_serial = 0
        self._decisive = False
        self._since_interim = 0


def _rms(samples: Samples) -> float:
    return float(np.sqrt(np.mean(np.square(samples, dtype=np.float64)))) if samples.size else 0.0
