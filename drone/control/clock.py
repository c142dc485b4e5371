"""Clocks injected into every time-dependent part (DESIGN §3 "Clock").

``MonotonicClock`` is real time for flight; ``VirtualClock`` only moves when told to, so a
lockstep simulation runs deterministically and faster than real time.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """Anything with ``now() -> seconds`` (monotonic, arbitrary origin)."""

    def now(self) -> float: ...


class MonotonicClock:
    """Real time: ``time.monotonic()`` — the clock the asyncio driver stamps its events with."""

    def now(self) -> float:
        return time.monotonic()


class VirtualClock:
    """A clock that only advances when :meth:`advance` or :meth:`set` is called (thread-safe)."""

    def __init__(self, start: float = 0.0) -> None:
        if not math.isfinite(start):
            raise ValueError(f"clock start must be finite, got {start!r}")
        self._now = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        return self._now

    def advance(self, dt: float) -> float:
        """Move forward by ``dt`` seconds and return the new time.

        Raises:
            ValueError: ``dt`` is negative or not finite (time never runs backwards).
        """
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be finite and >= 0, got {dt!r}")
        with self._lock:
            self._now += dt
            return self._now

    def set(self, t: float) -> None:
        """Jump to ``t`` (>= now).

        Raises:
            ValueError: ``t`` is earlier than now or not finite.
        """
        if not math.isfinite(t) or t < self._now:
            raise ValueError(f"cannot set the clock back from {self._now} to {t!r}")
        with self._lock:
            self._now = float(t)
