"""Per-connection limits, sans-I/O: a token bucket for frame rate and a bounded output queue."""

from __future__ import annotations

import collections


class TokenBucket:
    """``rate`` frames per second with bursts up to ``burst`` (time passed in)."""

    def __init__(self, rate: float, burst: float, now: float) -> None:
        self.rate = rate
        self.burst = burst
        self.tokens = burst
        self.updated = now

    def take(self, now: float) -> bool:
        return self.take_n(now, 1.0)

    def take_n(self, now: float, n: float) -> bool:
        """Take ``n`` tokens (e.g. bytes) if there are that many; True if taken."""
        self.tokens = min(self.burst, self.tokens + (now - self.updated) * self.rate)
        self.updated = now
        if self.tokens >= n:
            self.tokens -= n
            return True
        return False


class OutQueue:
    """Frames waiting for the socket; beyond ``max_frames`` or ``max_bytes`` the oldest go."""

    def __init__(self, max_frames: int, max_bytes: int) -> None:
        self.max_frames = max_frames
        self.max_bytes = max_bytes
        self._q: collections.deque[str | bytes] = collections.deque()
        self.bytes = 0
        self.dropped = 0

    def push(self, frame: str | bytes) -> None:
        self._q.append(frame)
        self.bytes += len(frame)
        while len(self._q) > 1 and (len(self._q) > self.max_frames or self.bytes > self.max_bytes):
            old = self._q.popleft()
            self.bytes -= len(old)
            self.dropped += 1

    def pop(self) -> str | bytes | None:
        if not self._q:
            return None
        frame = self._q.popleft()
        self.bytes -= len(frame)
        return frame

    def clear(self) -> None:
        """Drop every waiting frame (the connection closed: free the memory now)."""
        self._q.clear()
        self.bytes = 0

    def __len__(self) -> int:
        return len(self._q)
