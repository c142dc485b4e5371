"""How much audio the Whisper encoder is given: a 15 s window, not Whisper's 30 s.

Whisper pads every input to a 30 s window (openai/whisper audio.py: ``N_FRAMES = 3000`` log-mel
frames, 100 per second). Its encoder's cost grows faster than the window (the attention with its
square), so a 2 s command paid for 28 s of padding: tiny.en's encoder took 459 ms of one core
for a 2.3 s clip over 3 000 frames, 61 ms over 1 000 and 31 ms over 600 (CTranslate2 int8, this
project's 2-core machine). CTranslate2's Whisper encoder accepts any window up to 3 000 frames,
but Whisper, trained on 30 s windows only, hears less well in short ones: on 108 clips of
bench/speech.py's set (guided, 4 beams; clean / 20 dB / 10 dB exact match) 30 s windows gave
69 / 47 / 42 % at 602 ms p50, 20 s 67 / 56 / 50 % at 283 ms, 15 s 67 / 58 / 47 % at 217 ms,
10 s 61 / 58 / 50 % (8 beams) at 192 ms, and speech + 1 s only 28 / 25 / 19 % with 16 wrong
commands executed (it repeats itself: "Kill the motors." x 15). So: at least ``MIN_S``; longer
speech gets speech + ``PAD_S``, rounded up to whole seconds, up to the full window (longer
audio than that is decoded window by window, as faster-whisper does).
"""

from __future__ import annotations

FRAMES_PER_S = 100  # Whisper's log-mel hop: 160 samples at 16 kHz (openai/whisper audio.py)
FULL_WINDOW_FRAMES = 3000  # 30 s, the window Whisper was trained on (openai/whisper N_FRAMES)
MIN_S = 15.0  # the shortest window (measured above)
PAD_S = 1.0  # silence after speech longer than MIN_S - PAD_S
STEP_S = 1.0  # windows come in whole seconds


def window_frames(content_frames: int, min_s: float = MIN_S) -> int:
    """Encoder frames for ``content_frames`` of speech: at least ``min_s``, else content +
    ``PAD_S`` rounded up to whole ``STEP_S``, at most the full 30 s window."""
    if content_frames < 0:
        raise ValueError(f"content_frames must be >= 0, got {content_frames}")
    step = round(STEP_S * FRAMES_PER_S)
    wanted = max(round(min_s * FRAMES_PER_S), content_frames + round(PAD_S * FRAMES_PER_S))
    return min(FULL_WINDOW_FRAMES, -(-wanted // step) * step)


def fits(content_frames: int) -> bool:
    """Whether speech of ``content_frames`` and its pad fit in one window."""
    return content_frames + round(PAD_S * FRAMES_PER_S) <= FULL_WINDOW_FRAMES
