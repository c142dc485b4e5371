"""Replies spoken by the server, for browsers without a voice of their own.

Two voices, best first:

* **hibari** (PyPI ``hibari-tts``, Apache-2.0, the ``speech`` extra): a neural voice distilled
  from Kokoro-82M; its one bundled voice ("heart", American English) is used, and only from
  the package (``voice_path(..., download_missing=False)``): nothing is downloaded at run time.
  About 1 s to load and 2 s for the first sentence (its lexicon), then ~60-130 ms per reply on
  one core (bench/speech.py section 4);
* **espeak-ng** (Debian package ``espeak-ng``): formant synthesis, robotic but tens of
  milliseconds, the fallback when hibari is not installed or cannot load.

Synthesis is blocking CPU work: callers run it in a thread (server/api/tts.py).
"""

from __future__ import annotations

import io
import logging
import shutil
import subprocess
import threading
import wave
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from server.speech.errors import SynthesisError

log = logging.getLogger("uav_console.speech")

HIBARI_VOICE = "heart"  # the voice inside the hibari-tts wheel
ESPEAK_VOICE = "en-us"
WORDS_PER_MINUTE = 165  # espeak-ng's default is 175; a touch slower is clearer over a fan's noise
TIMEOUT_S = 10.0


class Voice(Protocol):
    """Text -> a WAV file's bytes."""

    @property
    def name(self) -> str:
        """Which voice, for the ``X-Voice`` header and the log."""
        ...

    def wav(self, text: str) -> bytes:
        """Raises: SynthesisError."""
        ...


def to_wav(samples: np.ndarray, rate: int) -> bytes:
    """16-bit mono PCM WAV of float samples in [-1, 1]."""
    pcm = (np.clip(samples, -1.0, 1.0) * 32767.0).astype("<i2")
    out = io.BytesIO()
    with wave.open(out, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(pcm.tobytes())
    return out.getvalue()


class NeuralVoice:
    """hibari-tts with its bundled voice; one synthesis at a time (its G2P keeps state)."""

    def __init__(self, model: Any, rate: int) -> None:
        self.name = f"hibari ({HIBARI_VOICE})"
        self._model = model
        self.rate = rate
        self._lock = threading.Lock()

    @classmethod
    def load(cls) -> NeuralVoice:
        """Load the bundled voice and warm its lexicon (~3 s of CPU).

        Raises:
            SynthesisError: hibari-tts is not installed or its voice cannot be loaded.
        """
        try:
            from hibari import SAMPLE_RATE, Hibari
            from hibari.voices import voice_path

            path = voice_path(HIBARI_VOICE, download_missing=False)
            model = Hibari(voice=HIBARI_VOICE, model=path, threads=1)
            model("Ready.")  # loads the G2P lexicon now, not during the first reply
        except ImportError as exc:
            raise SynthesisError("hibari-tts is not installed (the speech extra)") from exc
        except Exception as exc:  # onnxruntime, a damaged wheel: say why, fall back
            raise SynthesisError(f"hibari-tts could not load its voice: {exc}") from exc
        return cls(model, int(SAMPLE_RATE))

    def wav(self, text: str) -> bytes:
        with self._lock:
            try:
                samples = self._model(text, seed=0)
            except Exception as exc:  # the model's own failure, on text it cannot read
                raise SynthesisError(f"hibari-tts failed: {exc}") from exc
        if samples.size == 0:
            raise SynthesisError("hibari-tts produced no audio for this text")
        return to_wav(np.asarray(samples, dtype=np.float32), self.rate)


@dataclass(frozen=True)
class EspeakVoice:
    """espeak-ng as a process (``--stdout`` writes the WAV)."""

    exe: str
    name: str = "espeak-ng"

    def wav(self, text: str) -> bytes:
        # "--" ends the options: text starting with "-" is spoken, never read as a flag.
        cmd = [self.exe, "--stdout", "-v", ESPEAK_VOICE, "-s", str(WORDS_PER_MINUTE), "--", text]
        try:
            done = subprocess.run(cmd, capture_output=True, timeout=TIMEOUT_S, check=False)
        except subprocess.TimeoutExpired as exc:
            raise SynthesisError("speech synthesis timed out") from exc
        except OSError as exc:
            raise SynthesisError(f"espeak-ng could not run: {exc}") from exc
        if done.returncode != 0 or not done.stdout.startswith(b"RIFF"):
            why = done.stderr.decode(errors="replace").strip()[:200]
            raise SynthesisError(f"speech synthesis failed: {why or done.returncode}")
        return done.stdout


def espeak() -> EspeakVoice | None:
    """espeak-ng, or None when it is not installed."""
    exe = shutil.which("espeak-ng")
    return EspeakVoice(exe) if exe else None


def best_voice() -> Voice | None:
    """The neural voice where it loads, else espeak-ng, else None (said in the log)."""
    try:
        return NeuralVoice.load()
    except SynthesisError as exc:
        fallback = espeak()
        log.info("spoken replies: %s; %s", exc, "using espeak-ng" if fallback else "no voice")
        return fallback
