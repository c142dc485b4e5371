"""Speech tests: utterances synthesised at run time with espeak-ng, flite or hibari (voices,
speeds) and sox (noise at a chosen SNR, other rates, stereo), and one Whisper model loaded per
session.

Keep real decodes few: tiny.en takes ~0.3-1.5 s per clip on the 2-core machine.
"""

from __future__ import annotations

import functools
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from server.language.nlu import default_nlu
from server.speech.audio import read_wav, to_wav
from server.speech.recognizer import Recognizer
from server.speech.service import SpeechConfig, SpeechService

HAVE_TTS = shutil.which("espeak-ng") is not None and shutil.which("sox") is not None
needs_tts = pytest.mark.skipif(not HAVE_TTS, reason="espeak-ng and sox are needed (.ci/run)")

Synth = Callable[..., Path]
# hibari-tts (PyPI, Apache-2.0): a neural voice distilled from Kokoro-82M; its "heart" voice is
# in the wheel (the others download on first use, so they are never asked for here).
HIBARI_VOICES = ("heart",)


@functools.cache
def _hibari() -> Any:
    from hibari import Hibari

    return Hibari(voice="heart", threads=1)


def synthesise(
    out: Path,
    text: str,
    *,
    voice: str = "en-us",
    speed: int = 160,
    snr_db: float | None = None,
    rate: int = 16000,
    channels: int = 1,
    seed: int = 1,
    pad_s: float = 0.3,
    tts: str = "espeak-ng",
) -> Path:
    """``tts`` -> WAV at ``rate`` with ``channels``, white noise at ``snr_db`` (seeded), and
    ``pad_s`` of silence either side (as a microphone would hear it).

    ``tts`` is espeak-ng (formant synthesis; ``voice`` one of its voices, ``speed`` in words per
    minute), flite (Debian's CMU Flite: less robotic voices, "slt", "rms", "awb", "kal16";
    ``speed`` relative to 160 words per minute through its duration stretch) or hibari (a neural
    voice, "heart"; ``speed`` relative to 160 words per minute, its noise seeded by ``seed``)."""
    raw = out.with_suffix(".raw.wav")
    if tts == "hibari":
        if voice not in HIBARI_VOICES:
            raise ValueError(f"hibari voice {voice!r} is not in the package (only {HIBARI_VOICES})")
        _hibari().save(text, str(raw), speed=speed / 160, seed=seed)
        command: list[str] = []
    elif tts == "flite":
        stretch = f"duration_stretch={160 / speed:.3f}"
        command = ["flite", "-voice", voice, "--setf", stretch, "-t", text, "-o", str(raw)]
    elif tts == "espeak-ng":
        command = ["espeak-ng", "-v", voice, "-s", str(speed), "-w", str(raw), text]
    else:
        raise ValueError(f"unknown text-to-speech {tts!r} (espeak-ng, flite or hibari)")
    if command:
        subprocess.run(command, check=True, capture_output=True)
    samples = read_wav(raw.read_bytes())  # 16 kHz mono float
    pad = np.zeros(int(pad_s * 16000), np.float32)
    samples = np.concatenate([pad, samples, pad])
    if snr_db is not None:
        power = float(np.mean(samples[samples != 0] ** 2))
        rng = np.random.default_rng(seed)
        noise = rng.normal(0.0, np.sqrt(power / 10 ** (snr_db / 10)), samples.size)
        samples = (samples + noise).astype(np.float32)
    clean = out.with_suffix(".16k.wav")
    clean.write_bytes(to_wav(samples))
    subprocess.run(
        ["sox", str(clean), "-r", str(rate), "-c", str(channels), "-b", "16", str(out)],
        check=True,
        capture_output=True,
    )
    return out


@pytest.fixture
def synth(tmp_path: Path) -> Synth:
    if not HAVE_TTS:
        pytest.skip("espeak-ng and sox are needed (.ci/run installs them)")
    counter = iter(range(10_000))

    def make(text: str, **kw: object) -> Path:
        return synthesise(tmp_path / f"clip{next(counter)}.wav", text, **kw)  # type: ignore[arg-type]

    return make


@pytest.fixture(scope="session")
def recognizer() -> Recognizer:
    """The bundled tiny.en, loaded once for the whole session."""
    return SpeechService(SpeechConfig(workers=1), default_nlu()).load()
