"""Audio -> text with faster-whisper, then text -> a sentence the grammars accept.

Grammar guidance has three parts: the decoder is primed with the grammars' vocabulary
(:data:`server.speech.vocabulary.PROMPT`), may only write tokens that spell grammar words,
numbers and punctuation (:mod:`server.speech.constraint`), and its transcript is snapped to the
nearest sentence the NLU understands (:mod:`server.speech.snap`). ``guided=False`` turns all
three off: the baseline of ``bench/speech.py``.

Decoding options and why:
  * beam search with 4 beams, each of the 4 transcripts snapped to the grammars, the best
    supported reading kept (:func:`choose`); a single temperature (no fallback re-decodes): the
    time per clip must be bounded;
  * ``without_timestamps`` and no conditioning on earlier text: one utterance per call;
  * ``max_new_tokens=64``: a spoken command is far shorter; a hallucination loop stops there;
  * Silero VAD (shipped with faster-whisper) first: audio without speech is not decoded, which
    avoids Whisper's well-known hallucinations on silence ("Thank you.");
  * a 15 s encoder window instead of Whisper's 30 s (:mod:`server.speech.window`): the encoder
    is most of a decode's time; speech too long for one window goes through faster-whisper's
    own windowing.
"""

from __future__ import annotations

import copy
import math
import re
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from server.language.nlu import NLU
from server.speech.audio import SAMPLE_RATE, Samples
from server.speech.constraint import suppressed_tokens
from server.speech.memo import SharedResults, digest
from server.speech.snap import Snapped, Snapper, direction, opposite, same_commands
from server.speech.vocabulary import Vocabulary, vocabulary
from server.speech.window import MIN_S, fits, window_frames

Command = dict[str, Any]
# The constrained decoder (server.speech.constraint) renormalises each step's probability over
# the allowed tokens, so its mean token probability reads higher than the free decoder's for the
# same audio. Scaling it by 0.83 (= 0.5 / 0.6: the dialog's 0.5 threshold acts as 0.6) keeps
# wrong commands executed at the free decoder's rate or below: bench/speech.py, 324 clips, free
# decoder at 0.5 -> 2.5 % wrong, 35.8 % right; constrained at 0.5 -> 4.9 % / 42.6 %, at 0.6 ->
# 2.2 % / 37.7 %, at 0.65 -> 1.5 % / 35.5 % (the free one at 0.6: 1.5 % / 29.9 %).
CONSTRAINED_CONFIDENCE_SCALE = 0.83
# Beam width, and transcripts tried against the grammars (:func:`choose`): bench/speech.py's
# 108-clip subset, 15 s window: greedy 61 / 50 / 36 % exact (clean / 20 / 10 dB) at 179 ms p50,
# 4 beams 67 / 58 / 47 % at 217 ms, 8 beams the same at 251 ms.
BEAMS = 4
# A doubtful reading (:func:`doubt`) is capped just under the dialog's threshold, so it is read
# back ("Did you say …?") and never flown as heard.
DOUBT_MARGIN = 0.01
THRESHOLD = 0.5  # Settings.confidence_threshold's default
# A transcript heard at least this surely (the decoder's own confidence) that the grammars
# cannot read whole is a grammar gap, not a mishearing: hibari-tts's voice is heard at
# 0.87-0.97 when Whisper gets every word ("Hover for now and tell me your battery level." 0.96),
# espeak-ng's garbled readings mostly under 0.8 (bench/speech.py's clips).
GAP_CONFIDENCE = 0.85
# A doubtful reading (:func:`doubt`) is read back: another beam at this share of its decoder
# confidence reads whole as other commands, or heard other words where the reading moves the
# drone, or reads the opposite direction. Chosen on bench/speech.py's three clip sets (hibari,
# espeak-ng, flite; 972 clips): rival 0.5 / 0.7 cost hibari's set 1.8 / 0 points of exact
# match; contested 0.9 / 0.85 / 0.8 left 2 / 0 / 0 wrong commands flown on espeak-ng's set.
RIVAL_RATIO = 0.7
CONTESTED_RATIO = 0.85
OPPOSITE_RATIO = 0.3
MOTION = frozenset({"move", "turn", "goto", "patrol"})  # commands that fly the drone somewhere
MAX_NEW_TOKENS = 64  # a spoken command is far shorter; a hallucination loop stops there
VAD_PAD_S = 0.3  # speech kept either side of what the VAD marks (its own default is 0.4 s)
_SENTENCE_END = re.compile(r"(?<=[.?!])\s+")
_NOT_WORD = re.compile(r"[^\w\s]+")


@dataclass(frozen=True)
class Recognition:
    """What was said, as the dialog manager gets it."""

    text: str  # the sentence handed on (snapped when guided); "" when no speech was heard
    confidence: float  # 0..1: decoder confidence (x the constraint's scale) x the snap factor
    commands: list[Command] = field(default_factory=list)
    heard: str = ""  # the decoder's own transcript
    asr_confidence: float = 0.0
    snap_distance: float = 0.0
    audio_s: float = 0.0
    decode_ms: float = 0.0
    speech: bool = True  # False: the VAD found no speech, nothing was decoded
    reused: bool = False  # the same speech was decoded (or was being decoded) already
    # A grammar gap: the decoder's most confident transcript, heard plainly (at least
    # GAP_CONFIDENCE) and not read whole by the grammars as heard; "" when none.
    gap: str = ""
    doubt: str = ""  # why the reading is read back, not flown (:func:`doubt`); "" when not

    def as_json(self) -> dict[str, Any]:
        return {
            "text": self.text,
            "confidence": round(self.confidence, 4),
            "commands": self.commands,
            "heard": self.heard,
            "snap_distance": round(self.snap_distance, 4),
            "audio_s": round(self.audio_s, 3),
            "decode_ms": round(self.decode_ms, 1),
            "doubt": self.doubt,
        }


def speech_span(samples: Samples, *, min_silence_ms: int = 300) -> tuple[int, int] | None:
    """(start, end) sample indices of the speech in ``samples`` per Silero VAD; None if none."""
    from faster_whisper.vad import VadOptions, get_speech_timestamps

    spans = get_speech_timestamps(
        samples, VadOptions(min_silence_duration_ms=min_silence_ms, speech_pad_ms=0)
    )
    if not spans:
        return None
    pad = int(VAD_PAD_S * SAMPLE_RATE)
    return max(0, spans[0]["start"] - pad), min(len(samples), spans[-1]["end"] + pad)


class SileroStream:
    """Silero VAD's speech probability of each 512-sample frame of one stream, fed in order.

    Silero is recurrent: ``get_speech_timestamps`` runs a whole clip in one batch and carries
    the LSTM state from frame to frame. Scoring each new frame from a fresh state gives other
    probabilities (the end of "take off" three frames early), so the stream's speech would not
    be the speech a whole clip is trimmed to; this carries the state and the 64-sample context
    across calls, giving the whole clip's probabilities (faster_whisper.vad.SileroVADModel)."""

    def __init__(self) -> None:
        from faster_whisper.vad import get_vad_model

        self._session = get_vad_model().session
        self._h = np.zeros((1, 1, 128), np.float32)
        self._c = np.zeros((1, 1, 128), np.float32)
        self._context = np.zeros(64, np.float32)

    def __call__(self, samples: Samples) -> np.ndarray:
        n = len(samples) // 512
        if n == 0:
            return np.zeros(0, np.float32)
        frames = np.ascontiguousarray(samples[: n * 512], dtype=np.float32).reshape(n, 512)
        context = np.concatenate([self._context[None, :], frames[:-1, -64:]])
        batch = np.concatenate([context, frames], axis=1)
        out, self._h, self._c = self._session.run(
            None, {"input": batch, "h": self._h, "c": self._c}
        )
        self._context = frames[-1, -64:].copy()
        return np.ravel(out)


def _suppress_list(tokenizer: Any, vocab: Vocabulary) -> list[int]:
    """The guided ``suppress_tokens`` for a faster-whisper ``Tokenizer``: tokens outside the
    grammar vocabulary (:mod:`server.speech.constraint`) plus the model's non-speech symbols."""
    return suppressed_tokens(
        tokenizer.tokenizer, vocab.words, tokenizer.eot, tokenizer.non_speech_tokens
    )


class Recognizer:
    """A loaded Whisper model plus the grammars' vocabulary; ``recognize`` is thread-safe
    (CTranslate2 runs up to ``num_workers`` decodes in parallel; the snapper is read-only)."""

    def __init__(
        self,
        model: Any,
        nlu: NLU,
        *,
        vocab: Vocabulary | None = None,
        reuse: bool = True,
        window_s: float | None = MIN_S,
        beams: int = BEAMS,
        threshold: float = THRESHOLD,
    ) -> None:
        """``window_s``: the shortest encoder window (:mod:`server.speech.window`); None gives
        Whisper's own 30 s windows and greedy decoding (the earlier way, bench/speech.py's
        reference row). ``beams``: beam width and transcripts tried against the grammars.
        ``threshold``: the dialog's confidence threshold (Settings.confidence_threshold); a
        doubtful reading is kept under it (:data:`DOUBT_MARGIN`)."""
        from faster_whisper.tokenizer import Tokenizer
        from faster_whisper.transcribe import get_suppressed_tokens

        self.model = model
        self.nlu = nlu
        self.vocab = vocab or vocabulary(nlu.grammar)
        self.snapper = Snapper(nlu, self.vocab)
        self.window_s = window_s
        self.beams = beams
        self.cap = max(0.0, threshold - DOUBT_MARGIN)
        self._vad_lock = threading.Lock()  # Silero's ONNX session is shared; keep calls serial
        self._tokenizer = Tokenizer(
            model.hf_tokenizer, model.model.is_multilingual, task="transcribe", language="en"
        )
        self._suppress = _suppress_list(self._tokenizer, self.vocab)
        # What a fitted-window decode passes CTranslate2, guided (True) or not, made once: the
        # suppress list is ~44 000 ids, and completing it cost 1.5 ms of GIL per decode.
        prompt_tokens = self._tokenizer.encode(" " + self.vocab.prompt.strip())
        self._prompts = {
            g: model.get_prompt(
                self._tokenizer, prompt_tokens if g else [], without_timestamps=True
            )
            for g in (True, False)
        }
        self._suppress_ids = {
            True: get_suppressed_tokens(self._tokenizer, list(self._suppress)),
            False: get_suppressed_tokens(self._tokenizer, [-1]),
        }
        # reuse=False: every call decodes (bench/speech.py decodes one clip over and over).
        self.shared: SharedResults[Recognition] | None = SharedResults(size=8) if reuse else None

    def warm_up(self) -> None:
        """Decode a second of quiet noise once: CTranslate2's first decode costs about half as
        much CPU again as the next ones (167 vs 108-126 ms for "take off" on this project's
        2-core machine), which the operator's first command should not pay."""
        noise = np.random.default_rng(0).normal(0.0, 1e-3, SAMPLE_RATE).astype(np.float32)
        self.hypotheses(noise, guided=True)

    def hypotheses(self, samples: Samples, *, guided: bool = True) -> list[tuple[str, float]]:
        """The decoder's best transcripts, best first, each with its confidence in 0..1."""
        if self.window_s is None:
            return [self._transcribe_windows(samples, guided)]
        features = self.model.feature_extractor(samples)
        content = features.shape[-1] - 1  # faster-whisper's count: the last frame is padding
        if not fits(content):
            return [self._transcribe_windows(samples, guided)]
        return self._transcribe_fitted(features[:, :content], guided, self.window_s)

    def _transcribe_fitted(
        self, content: np.ndarray, guided: bool, min_s: float
    ) -> list[tuple[str, float]]:
        """One decode over a window of at least ``min_s`` fitted to the speech
        (:mod:`server.speech.window`), with the options faster-whisper's ``transcribe`` would
        use (see the module docstring)."""
        from faster_whisper.audio import pad_or_trim

        encoder_output = self.model.encode(
            pad_or_trim(content, window_frames(content.shape[-1], min_s))
        )
        prompt = self._prompts[guided]
        result = self.model.model.generate(
            encoder_output,
            [prompt],
            beam_size=self.beams,
            num_hypotheses=self.beams,
            max_length=len(prompt) + MAX_NEW_TOKENS,
            return_scores=True,
            return_no_speech_prob=True,
            suppress_blank=True,
            suppress_tokens=self._suppress_ids[guided],
        )[0]
        out: list[tuple[str, float]] = []
        for tokens, score in zip(result.sequences_ids, result.scores, strict=True):
            text = self._tokenizer.decode(tokens).strip()
            if not text:
                out.append(("", 0.0))
                continue
            # faster-whisper's average log probability: the score is length-normalised over
            # the tokens, the average counts the end-of-text token too.
            avg_logprob = score * len(tokens) / (len(tokens) + 1)
            confidence = math.exp(avg_logprob) * (1.0 - result.no_speech_prob)
            out.append((text, min(1.0, max(0.0, confidence))))
        return out or [("", 0.0)]

    def _transcribe_windows(self, samples: Samples, guided: bool) -> tuple[str, float]:
        """faster-whisper's own decode: 30 s windows, one after another."""
        segments, _info = self.model.transcribe(
            samples,
            language="en",
            beam_size=1,
            temperature=0.0,
            without_timestamps=True,
            condition_on_previous_text=False,
            initial_prompt=self.vocab.prompt if guided else None,
            max_new_tokens=MAX_NEW_TOKENS,
            vad_filter=False,
            # A copy: faster-whisper extends the list it is given.
            suppress_tokens=list(self._suppress) if guided else [-1],
        )
        texts: list[str] = []
        logprob_sum = 0.0
        weight = 0.0
        no_speech = 0.0
        for seg in segments:
            texts.append(seg.text)
            n = max(1, len(seg.tokens))
            logprob_sum += seg.avg_logprob * n
            weight += n
            no_speech = max(no_speech, seg.no_speech_prob)
        text = " ".join(t.strip() for t in texts).strip()
        if not text or weight == 0:
            return "", 0.0
        confidence = math.exp(logprob_sum / weight) * (1.0 - no_speech)
        return text, min(1.0, max(0.0, confidence))

    def recognize(
        self, samples: Samples, *, guided: bool = True, state: str | None = None, vad: bool = True
    ) -> Recognition:
        """Decode, snap (when ``guided``) and interpret one utterance.

        Speech already decoded (or being decoded) with the same guidance and state, e.g. by the
        stream's speculative decode, is not decoded again (:mod:`server.speech.memo`)."""
        t0 = time.perf_counter()
        audio_s = len(samples) / SAMPLE_RATE
        if vad:
            with self._vad_lock:
                span = speech_span(samples)
            if span is None:
                return Recognition("", 0.0, audio_s=audio_s, speech=False)
            samples = samples[span[0] : span[1]]
        if not np.isfinite(samples).all():
            samples = np.nan_to_num(samples, nan=0.0, posinf=0.0, neginf=0.0)
        if self.shared is None:
            rec, reused = self._decode(samples, guided, state), False
        else:
            key = (digest(samples), guided, state)
            rec, reused = self.shared.get(key, lambda: self._decode(samples, guided, state))
        ms = (time.perf_counter() - t0) * 1000
        # A copy of the commands: whoever gets a shared result may change its own.
        commands = copy.deepcopy(rec.commands)
        return replace(rec, commands=commands, audio_s=audio_s, decode_ms=ms, reused=reused)

    def _decode(self, samples: Samples, guided: bool, state: str | None) -> Recognition:
        """Decode, snap and interpret speech already trimmed by the VAD."""
        hypotheses = self.hypotheses(samples, guided=guided)
        if guided:
            return choose(hypotheses, self.snapper, state, cap=self.cap)
        heard, asr = hypotheses[0]
        if not heard:
            return Recognition("", 0.0)
        return Recognition(heard, asr, self.nlu.interpret(heard, state), heard, asr, 0.0)


def unrepeated(text: str) -> str:
    """``text`` once when it is one sentence said over and over ("Kill the motors. Kill the
    motors."), else ``text``.

    Whisper's beams often repeat a short utterance (45 of 2 592 transcripts on bench/speech.py's
    two clip sets, 7 of the 324 flite clips' chosen readings); read as heard, the commands would
    run twice: a move flown twice as far. Said twice on purpose, it is flown once, the safer
    mistake.
    """
    sentences = [s for s in _SENTENCE_END.split(text.strip()) if s]
    if len(sentences) < 2:
        return text
    words = {" ".join(_NOT_WORD.sub(" ", s).lower().split()) for s in sentences}
    return sentences[0] if len(words) == 1 else text


def choose(
    hypotheses: list[tuple[str, float]],
    snapper: Snapper,
    state: str | None = None,
    cap: float = 1.0,
) -> Recognition:
    """The reading of the decoder's n best transcripts that the grammars support best.

    Each transcript is snapped to the grammars; its confidence is the decoder's
    (x :data:`CONSTRAINED_CONFIDENCE_SCALE`) x the snap's factor. The most confident reading
    the grammars understand whole wins; when none is understood whole, the most confident
    reading (the dialog then asks to repeat). A beam's second transcript that the grammars accept
    as heard ("Take off.") thus beats a likelier first one they cannot read ("Take off in the
    hand man."), which greedy decoding could not offer.

    A doubtful reading (:func:`doubt`) keeps at most ``cap``: the recogniser passes just under
    the dialog's threshold, so it is read back ("Did you say …?"), never flown as heard.
    """
    readings: list[_Reading] = []
    best: Recognition | None = None
    best_whole: Recognition | None = None
    seen: set[str] = set()
    plain = max(hypotheses, key=lambda h: h[1], default=("", 0.0))
    gap = ""
    for transcript, asr in hypotheses:
        heard = unrepeated(transcript)
        if not heard or heard in seen:  # beams often differ only after the words end
            continue
        seen.add(heard)
        if snapper.nlu.answer(heard) is not None:
            # "Yes." answers the dialog's "Did you say …?": handed on as heard (the NLU reads
            # "yes" as a filler, and a snap would bend it into a command).
            confidence = asr * CONSTRAINED_CONFIDENCE_SCALE
            rec = Recognition(heard, confidence, [], heard, asr, 0.0)
            readings.append(_Reading(heard, asr, None))
            whole = True
        else:
            snapped = snapper.snap(heard, state)
            confidence = asr * CONSTRAINED_CONFIDENCE_SCALE * snapped.factor
            if snapped.distance > 0:  # bent: a guess (see doubt), never more than read back
                confidence = min(confidence, cap)
            rec = Recognition(
                snapped.text.strip(" ,"), confidence, snapped.commands, heard, asr, snapped.distance
            )
            readings.append(_Reading(heard, asr, snapped))
            whole = snapped.complete and bool(snapped.commands)
            if transcript == plain[0] and asr >= GAP_CONFIDENCE and not snapped.whole_as_heard:
                gap = heard  # Whisper heard it plainly; the grammars could not read it whole
        if best is None or confidence > best.confidence:
            best = rec
        if whole and (best_whole is None or confidence > best_whole.confidence):
            best_whole = rec
    chosen = best_whole or best or Recognition("", 0.0)
    why = doubt(chosen, readings)
    if why:
        chosen = replace(chosen, confidence=min(chosen.confidence, cap), doubt=why)
    return replace(chosen, gap=gap) if gap else chosen


@dataclass(frozen=True)
class _Reading:
    """One distinct transcript of the beam and what the grammars made of it."""

    heard: str
    asr: float
    snapped: Snapped | None  # None: an answer ("Yes.")

    def agrees(self, commands: list[Command]) -> bool:
        """Read whole as heard, as ``commands`` or the first of them: a beam that ended
        early ("Take off and go to marker two." beside "… two then land.") agrees."""
        s = self.snapped
        if s is None or not s.whole_as_heard or len(s.commands) > len(commands):
            return False
        return same_commands(s.commands, commands[: len(s.commands)])


def doubt(chosen: Recognition, readings: list[_Reading]) -> str:
    """Why ``chosen`` must be read back rather than flown, or "" (bench/speech.py's three clip
    sets, 972 clips: these rules take the wrong commands flown from 8 to none):

    * ``snap``: it was bent to fit the grammars (a snap is a guess: of the 972 clips' flown
      readings only 4 were snapped, one of them wrong: "Go still." flown to a chair);
    * ``rival``: another beam, at :data:`RIVAL_RATIO` of its confidence or more, reads whole
      as other commands ("Can you travel to waypoint seven now?" beside "… a point seven");
    * ``contested``: it moves the drone and another beam nearly as confident
      (:data:`CONTESTED_RATIO`) heard words that do not read as the same commands, even
      snapped ("Please turn right." beside "Please don't right.", "Head to marker eight"
      beside "Head to marker, I"): the words that fly were in doubt ("Fly to marker at
      eleven." beside "Fly to marker 11." is no doubt: both read marker 11);
    * ``opposite``: a beam, even a weak one (:data:`OPPOSITE_RATIO`), reads whole as heard
      the opposite direction ("Climb immediately." beside "Landing immediately.").
    """
    if not chosen.commands:
        return ""
    if chosen.snap_distance > 0:
        return "snap"
    mine = {d for c in chosen.commands if (d := direction(c)) is not None}
    moves = any(c.get("action") in MOTION for c in chosen.commands)
    asr = chosen.asr_confidence  # the other beams are measured against it
    why = ""
    for r in readings:
        if r.heard == chosen.heard or r.agrees(chosen.commands):
            continue
        s = r.snapped
        theirs = s.commands if s is not None and s.complete else []
        if theirs and s is not None and s.distance == 0 and r.asr >= RIVAL_RATIO * asr:
            return "rival"
        if (
            moves
            and r.asr >= CONTESTED_RATIO * asr
            and not (s is not None and s.complete and same_commands(s.commands, chosen.commands))
        ):
            why = why or "contested"
        heard_whole = s is not None and s.whole_as_heard  # a snapped beam is no evidence here
        if (
            heard_whole
            and r.asr >= OPPOSITE_RATIO * asr
            and any(opposite(d) in mine for c in theirs if (d := direction(c)) is not None)
        ):
            return "opposite"
    return why
