"""WAV bytes -> 16 kHz mono float32 samples, the only input the recogniser takes (sans-I/O).

Any sample rate, mono or stereo, 16-bit PCM. Stereo is averaged to mono;
other rates are resampled with libswresample through PyAV (already a dependency for video), which
low-pass filters before decimating, so 44.1/48 kHz microphone audio does not alias.
"""

from __future__ import annotations

import io
import wave

import numpy as np
import numpy.typing as npt

from server.speech.errors import AudioTooLong, EmptyAudio, NotWav

SAMPLE_RATE = 16_000  # Whisper's input rate (openai/whisper audio.py SAMPLE_RATE)
MAX_REQUEST_S = 30.0  # one request: Whisper's own window (openai/whisper audio.py CHUNK_LENGTH)

Samples = npt.NDArray[np.float32]


def read_wav(data: bytes, *, max_seconds: float = MAX_REQUEST_S) -> Samples:
    """Decode a WAV file held in memory.

    Raises:
        NotWav: not RIFF/WAVE, compressed, not 16-bit, more than two channels, or truncated
            header.
        EmptyAudio: no samples.
        AudioTooLong: longer than ``max_seconds`` (checked from the header, before decoding).
    """
    if len(data) < 12 or data[:4] != b"RIFF" or data[8:12] != b"WAVE":
        raise NotWav("not a WAV file (no RIFF/WAVE header)")
    try:
        with wave.open(io.BytesIO(data), "rb") as w:
            channels, width, rate, frames = (
                w.getnchannels(),
                w.getsampwidth(),
                w.getframerate(),
                w.getnframes(),
            )
            if width != 2:
                raise NotWav(f"WAV with {8 * width}-bit samples; 16-bit PCM is required")
            if channels not in (1, 2):
                raise NotWav(f"WAV with {channels} channels; mono or stereo is required")
            if not 4000 <= rate <= 192_000:
                raise NotWav(f"WAV sample rate {rate} Hz is outside 4000-192000 Hz")
            if frames / rate > max_seconds:
                raise AudioTooLong(
                    f"{frames / rate:.1f} s of audio; at most {max_seconds:.0f} s per request"
                )
            raw = w.readframes(frames)
    # The wave module also raises EOFError, RuntimeError (chunk bookkeeping) and struct.error
    # (a ValueError) on mangled headers; all mean the same thing here.
    except (wave.Error, EOFError, RuntimeError, ValueError) as exc:
        raise NotWav(f"not a usable WAV file: {exc}") from exc
    pcm = np.frombuffer(raw[: len(raw) - len(raw) % (2 * channels)], dtype="<i2")
    if pcm.size == 0:
        raise EmptyAudio("the WAV file holds no samples")
    samples = pcm.reshape(-1, channels).astype(np.float32).mean(axis=1) / 32768.0
    return resample(samples, rate)


def pcm16_to_float(data: bytes) -> Samples:
    """Little-endian 16-bit mono PCM (the browser stream's frames) as float32 in [-1, 1)."""
    usable = len(data) - len(data) % 2
    return np.frombuffer(data[:usable], dtype="<i2").astype(np.float32) / 32768.0


def resample(samples: Samples, rate: int) -> Samples:
    """Mono float32 at ``rate`` -> mono float32 at 16 kHz."""
    if rate == SAMPLE_RATE:
        return np.ascontiguousarray(samples, dtype=np.float32)
    import av  # lazy: only other rates need libswresample

    resampler = av.AudioResampler(format="flt", layout="mono", rate=SAMPLE_RATE)
    frame = av.AudioFrame.from_ndarray(
        np.ascontiguousarray(samples, dtype=np.float32).reshape(1, -1), format="flt", layout="mono"
    )
    frame.sample_rate = rate
    out = [f.to_ndarray().reshape(-1) for f in resampler.resample(frame)]
    out += [f.to_ndarray().reshape(-1) for f in resampler.resample(None)]
    return np.concatenate(out).astype(np.float32) if out else np.zeros(0, np.float32)


def to_wav(samples: Samples, rate: int = SAMPLE_RATE) -> bytes:
    """Float samples as a 16-bit mono WAV file (tests, benchmarks, debugging)."""
    pcm = (np.clip(samples, -1.0, 32767 / 32768) * 32768.0).astype("<i2")
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(pcm.tobytes())
    return buf.getvalue()
