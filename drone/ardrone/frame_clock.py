"""Capture times of video frames on the host's clock, from their PaVE timestamps (sans-I/O).

Each PaVE header carries the frame's timestamp in ms on the drone's own clock (ARDroneLib
``Soft/Common/video_encapsulation.h``, ``parrot_video_encapsulation_t.timestamp``; see
``video.py``). The host decodes the
frame some time later, so ``received − timestamp`` is the clock offset plus that frame's delay
(encoding, Wi-Fi, decoding, queueing). The smallest value over a sliding window is the offset plus
the *least* delay; ``timestamp + that minimum`` is then the capture time, late only by the least
delay and free of the jitter a fixed "received − 50 ms" guess carries. The window lets the
estimate follow clock drift; a timestamp that runs backwards (drone reboot, the 32-bit ms counter
wrapping after 49.7 days) starts it afresh.
"""

from __future__ import annotations

import math
from collections import deque

BACKWARDS_RESET_MS = 1000
"""A timestamp this much older than the last one means a new clock, not a reordered frame."""


class FrameClock:
    """Maps PaVE timestamps (drone ms) to host seconds by the minimum offset over a window."""

    def __init__(self, window_s: float = 10.0) -> None:
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s must be positive, not {window_s!r}")
        self.window_s = window_s
        self.frames = 0
        self.resets = 0
        self._last_ms: int | None = None
        # (received_s, offset_s) with offsets increasing: the front is the window's minimum.
        self._offsets: deque[tuple[float, float]] = deque()

    def stamp(self, timestamp_ms: int, received_s: float) -> float:
        """Host time (the clock of ``received_s``) at which the frame stamped ``timestamp_ms``
        was captured, plus the least delay seen in the window; never later than ``received_s``."""
        if self._last_ms is not None and timestamp_ms < self._last_ms - BACKWARDS_RESET_MS:
            self._offsets.clear()
            self.resets += 1
        self._last_ms = timestamp_ms
        self.frames += 1
        offset = received_s - timestamp_ms / 1000.0
        while self._offsets and self._offsets[-1][1] >= offset:
            self._offsets.pop()
        self._offsets.append((received_s, offset))
        while self._offsets[0][0] < received_s - self.window_s:
            self._offsets.popleft()
        return timestamp_ms / 1000.0 + self._offsets[0][1]
