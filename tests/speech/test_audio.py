"""WAV decoding: what each kind of bad input gets (no model needed)."""

from __future__ import annotations

import contextlib
import io
import struct
import wave

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.speech.audio import SAMPLE_RATE, pcm16_to_float, read_wav, to_wav
from server.speech.errors import AudioError, AudioTooLong, EmptyAudio, NotWav


def wav_bytes(samples: np.ndarray, rate: int, channels: int = 1, width: int = 2) -> bytes:
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(width)
        w.setframerate(rate)
        w.writeframes(samples.tobytes())
    return buf.getvalue()


def tone(rate: int, seconds: float, hz: float = 440.0) -> np.ndarray:
    t = np.arange(int(rate * seconds)) / rate
    return (0.5 * np.sin(2 * np.pi * hz * t) * 32767).astype("<i2")


def test_16k_mono_round_trip() -> None:
    x = tone(SAMPLE_RATE, 0.5)
    y = read_wav(wav_bytes(x, SAMPLE_RATE))
    assert y.dtype == np.float32 and len(y) == len(x)
    assert np.allclose(y, x / 32768.0)


@pytest.mark.parametrize("rate", [8000, 22050, 44100, 48000])
def test_any_rate_is_resampled_to_16k_keeping_the_tone(rate: int) -> None:
    y = read_wav(wav_bytes(tone(rate, 1.0, 440.0), rate))
    assert abs(len(y) - SAMPLE_RATE) <= 64
    spectrum = np.abs(np.fft.rfft(y[1000:-1000]))
    peak_hz = np.argmax(spectrum) * SAMPLE_RATE / (len(y) - 2000)
    assert abs(peak_hz - 440.0) < 3.0


def test_stereo_is_averaged_to_mono() -> None:
    left = tone(SAMPLE_RATE, 0.2)
    both = np.stack([left, np.zeros_like(left)], axis=1).reshape(-1)
    y = read_wav(wav_bytes(both, SAMPLE_RATE, channels=2))
    assert len(y) == len(left)
    assert np.allclose(y, left / 65536.0, atol=1e-4)


def test_not_audio() -> None:
    with pytest.raises(NotWav, match="not a WAV"):
        read_wav(b"%PDF-1.7 this is a document, not audio")


def test_zero_length_file() -> None:
    with pytest.raises(NotWav):
        read_wav(b"")


def test_header_without_samples() -> None:
    with pytest.raises(EmptyAudio):
        read_wav(wav_bytes(np.zeros(0, "<i2"), SAMPLE_RATE))


def test_ten_minutes_is_refused_from_the_header_without_decoding() -> None:
    # A header claiming 10 minutes with only a few bytes behind it: refused before reading.
    data = bytearray(wav_bytes(tone(SAMPLE_RATE, 0.01), SAMPLE_RATE))
    frames = 10 * 60 * SAMPLE_RATE
    struct.pack_into("<I", data, 40, frames * 2)  # data chunk size
    with pytest.raises(AudioTooLong, match=r"600\.0 s"):
        read_wav(bytes(data))


def test_eight_bit_and_many_channels_are_refused() -> None:
    with pytest.raises(NotWav, match="16-bit"):
        read_wav(wav_bytes(np.zeros(100, np.uint8), 8000, width=1))
    with pytest.raises(NotWav, match="channels"):
        read_wav(wav_bytes(np.zeros(600, "<i2"), 8000, channels=6))


def test_truncated_data_is_read_as_far_as_it_goes() -> None:
    data = wav_bytes(tone(SAMPLE_RATE, 0.1), SAMPLE_RATE)
    y = read_wav(data[:-101])  # an odd number of bytes cut: the partial sample is dropped
    assert 0 < len(y) < SAMPLE_RATE * 0.1


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=2000))
def test_arbitrary_bytes_decode_or_raise_audio_error(data: bytes) -> None:
    try:
        y = read_wav(data)
    except AudioError:
        return
    assert y.dtype == np.float32


@settings(max_examples=100, deadline=None)
@given(st.binary(min_size=44, max_size=400))
def test_arbitrary_bytes_behind_a_riff_header(data: bytes) -> None:
    with contextlib.suppress(AudioError):
        read_wav(b"RIFF" + data[4:8] + b"WAVE" + data[12:])


def test_pcm16_and_to_wav() -> None:
    x = np.array([0, 16384, -32768, 32767], "<i2")
    assert np.allclose(pcm16_to_float(x.tobytes() + b"\x01"), x / 32768.0)
    assert np.allclose(read_wav(to_wav(x / 32768.0)), x / 32768.0)
