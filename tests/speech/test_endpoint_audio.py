"""The stream's end-pointer on spoken audio: espeak-ng clips from files, Silero VAD's real
frame scores, the speculation told back as decisive at once (the earliest end the stream can
make: a decode of no time). No decoder, no socket, no clock but the samples fed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from server.speech.audio import SAMPLE_RATE, read_wav
from server.speech.recognizer import SileroStream
from server.speech.stream import LISTEN_S, Final, Speculation, StreamSession
from tests.speech.conftest import needs_tts, synthesise

pytestmark = needs_tts


def said(tmp_path: Path, text: str) -> np.ndarray:
    """``text`` spoken, from its first audible sample to its last (-60 dBFS): espeak-ng's
    own silence after a sentence (0.35 s) is no part of a pause here."""
    name = "".join(c if c.isalnum() else "_" for c in text)
    wav = synthesise(tmp_path / f"{name}.wav", text, voice="en-us", speed=160, pad_s=0.0)
    samples = read_wav(wav.read_bytes())
    loud = np.flatnonzero(np.abs(samples) >= 2**-10)
    return samples[loud[0] : loud[-1] + 1]


def quiet(seconds: float) -> np.ndarray:
    return np.zeros(int(seconds * SAMPLE_RATE), np.float32)


def finals_of(audio: np.ndarray) -> tuple[list[Final], StreamSession]:
    """Hands-free, in the page's 32 ms frames; every speculation is decisive at once."""
    s = StreamSession("handsfree", score=SileroStream())
    pcm = (np.clip(audio, -1, 1) * 32767).astype("<i2").tobytes()
    out: list[Final] = []
    for i in range(0, len(pcm), 1024):
        events = s.feed(pcm[i : i + 1024])
        while events:
            ev = events.pop(0)
            if isinstance(ev, Speculation):
                events[:0] = s.decided(ev.serial, True)
            elif isinstance(ev, Final):
                out.append(ev)
    return out, s


def test_a_command_ends_at_its_short_pause_and_keeps_its_last_sound(tmp_path: Path) -> None:
    speech = said(tmp_path, "take off")
    audio = np.concatenate([quiet(0.5), speech, quiet(1.0)])
    (final,), s = finals_of(audio)
    assert final.trimmed and s.committed == 1
    # All the speech is in it (up to the clip's last audible sample), and at most the
    # pre-roll and settle_s of silence besides.
    heard = np.flatnonzero(np.abs(final.samples) >= 2**-10)  # 16-bit PCM: a sample's jitter
    assert heard[-1] - heard[0] + 1 >= len(speech) - 0.005 * SAMPLE_RATE
    assert len(final.samples) <= len(speech) + 0.7 * SAMPLE_RATE


@pytest.mark.parametrize("pause_s", [0.1, 0.2])
def test_a_pause_mid_sentence_does_not_cut_it(tmp_path: Path, pause_s: float) -> None:
    """The first half reads whole ("take off") and is told decisive at once; a pause shorter
    than commit_s less what Silero hears as silence of a soft last consonant ("off": ~0.1 s)
    does not end it."""
    first, second = said(tmp_path, "take off"), said(tmp_path, "and fly to marker three")
    audio = np.concatenate([quiet(0.5), first, quiet(pause_s), second, quiet(1.0)])
    finals, _ = finals_of(audio)
    assert len(finals) == 1
    assert len(finals[0].samples) >= len(first) + len(second)


def test_a_long_pause_makes_two_utterances(tmp_path: Path) -> None:
    first, second = said(tmp_path, "take off"), said(tmp_path, "land")
    audio = np.concatenate([quiet(0.5), first, quiet(1.0), second, quiet(1.0)])
    finals, s = finals_of(audio)
    assert len(finals) == 2 and s.utterances == 2
    assert len(finals[0].samples) < len(first) + 0.7 * SAMPLE_RATE


def first_speculation(audio: np.ndarray, **options: float) -> tuple[Speculation, int]:
    """The first speculation of a hands-free stream and the samples fed when it was asked."""
    s = StreamSession("handsfree", score=SileroStream(), **options)
    pcm = (np.clip(audio, -1, 1) * 32767).astype("<i2").tobytes()
    for i in range(0, len(pcm), 1024):
        for ev in s.feed(pcm[i : i + 1024]):
            if isinstance(ev, Speculation):
                return ev, (i + 1024) // 2
    raise AssertionError("no speculation")


@pytest.mark.parametrize("text", ["take off", "land the drone", "hold still"])
def test_the_decode_starts_after_listen_s_on_the_speech_it_would_get_later(
    tmp_path: Path, text: str
) -> None:
    """The speculation is asked LISTEN_S after Silero hears the speech end, not settle_s, and
    (a pad of digital silence) holds the very samples one asked after settle_s would: the
    decode, and so the reading, is the same, only earlier."""
    speech = said(tmp_path, text)
    audio = np.concatenate([quiet(0.5), speech, quiet(1.0)])
    early, fed_early = first_speculation(audio)
    late, fed_late = first_speculation(audio, listen_s=0.3)
    assert np.array_equal(early.samples, late.samples)
    frames = -(-int(0.3 * SAMPLE_RATE) // 512) - round(LISTEN_S * SAMPLE_RATE / 512)
    assert fed_late - fed_early == frames * 512  # whole frames of silence: 10 against 4
    spoken_to = int(0.5 * SAMPLE_RATE) + len(speech)  # the last audible sample
    assert fed_early - spoken_to <= LISTEN_S * SAMPLE_RATE + 3 * 512  # Silero's lag: <= 3 frames
