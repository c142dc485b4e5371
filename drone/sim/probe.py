"""``ProbeSim``: the simulator, recording when commands reach its wire (benchmarks, tests).

Emergency latency is measured where it matters, at the drone: the monotonic time at which the
simulator's AT socket receives the first ``AT*REF`` with the emergency bit (bit 8, Developer
Guide §6.6) after a request. :class:`SimThread` runs one in a thread with its own event loop, so
the process that measures never shares a loop (or a stall) with the server under test.
"""

from __future__ import annotations

import asyncio
import re
import threading
import time
from typing import Any

from drone.sim.server import SimServer

REF_RE = re.compile(rb"AT\*REF=\d+,(-?\d+)")
EMERGENCY_BIT = 1 << 8  # AT*REF bit 8: emergency toggle (SDK 2.0 Developer Guide §6.6)
TAKEOFF_BIT = 1 << 9


class ProbeSim(SimServer):
    """A :class:`SimServer` that timestamps ``AT*REF`` commands with the emergency bit, and the
    first of each run of REFs with the take-off bit (a take-off reaching the drone)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.emergency_times: list[float] = []  # monotonic, each REF with bit 8 set
        self.takeoff_times: list[float] = []  # monotonic, each REF with bit 9 after one without
        self._takeoff_held = False
        self.datagrams = 0

    def _at(self, data: bytes) -> None:
        self.datagrams += 1
        for m in REF_RE.finditer(data):
            ref = int(m.group(1))
            if ref & EMERGENCY_BIT:
                self.emergency_times.append(time.monotonic())
            held = bool(ref & TAKEOFF_BIT)
            if held and not self._takeoff_held:
                self.takeoff_times.append(time.monotonic())
            self._takeoff_held = held
        super()._at(data)

    def first_takeoff_after(self, t0: float) -> float | None:
        """The first take-off REF (bit 9 rising) at or after monotonic ``t0`` (None: none)."""
        return next((t for t in self.takeoff_times if t >= t0), None)

    def first_emergency_after(self, t0: float) -> float | None:
        """The first emergency REF received at or after monotonic ``t0`` (None: none yet)."""
        return next((t for t in self.emergency_times if t >= t0), None)


class SimThread:
    """Run a :class:`ProbeSim` on its own loop in a daemon thread (``with SimThread(...)``)."""

    def __init__(self, addr: str, world: Any = "indoor", *, seed: int = 1) -> None:
        self.loop = asyncio.new_event_loop()
        self.sim = ProbeSim(addr, world, seed=seed)
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)

    def __enter__(self) -> SimThread:
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self.sim.start(), self.loop).result(10)
        return self

    def __exit__(self, *exc: object) -> None:
        asyncio.run_coroutine_threadsafe(self.sim.stop(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(5)
        self.loop.close()

    def call(self, fn: Any, *args: Any) -> Any:
        """Run ``fn(*args)`` on the simulator's loop and return its result."""

        async def run() -> Any:
            return fn(*args)

        return asyncio.run_coroutine_threadsafe(run(), self.loop).result(10)

    @property
    def truth(self) -> Any:
        return self.call(lambda: self.sim.truth)
