"""A bounded pool of decoders: at most ``workers`` decodes at once, at most ``queue`` waiting.

Decoding is CPU-bound (CTranslate2 releases the GIL while it computes), so it runs on a
dedicated thread pool, never on the event loop and never on the default executor the rest of
the server uses. A request that would have to wait behind ``queue`` others is refused at once
with :class:`Busy` (HTTP 503 with Retry-After) instead of piling up: back-pressure, so memory
and latency stay bounded when 20 streams speak at once, and the flight stack keeps its cores.
Interim (while-speaking) decodes only run on an idle worker (:meth:`try_run`): they are a
nicety and must never delay a final one.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import ParamSpec, TypeVar

from server.speech.errors import Busy

P = ParamSpec("P")
T = TypeVar("T")


class DecoderPool:
    """``await pool.run(fn, *args)`` runs ``fn`` on a decoder thread, or raises Busy."""

    def __init__(self, workers: int, queue: int) -> None:
        if workers < 1 or queue < 0:
            raise ValueError("a decoder pool needs at least one worker and a queue length >= 0")
        self.workers = workers
        self.queue = queue
        self._executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="asr")
        self._running = 0
        self._waiting = 0
        self._slots = asyncio.Semaphore(workers)
        self.refused = 0  # requests refused with Busy since start (for /health and tests)

    @property
    def busy(self) -> bool:
        return self._running >= self.workers

    @property
    def load(self) -> tuple[int, int]:
        """(running, waiting)."""
        return self._running, self._waiting

    async def run(self, fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
        """Run ``fn(*args, **kwargs)`` on a decoder; waits while all are busy.

        Raises:
            Busy: ``queue`` requests are already waiting.
        """
        if self._running >= self.workers and self._waiting >= self.queue:
            self.refused += 1
            raise Busy(
                f"all {self.workers} speech decoders are busy and {self._waiting} requests wait; "
                "try again in a moment"
            )
        self._waiting += 1
        try:
            await self._slots.acquire()
        finally:
            self._waiting -= 1
        return await self._on_slot(fn, *args, **kwargs)

    async def try_run(self, fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T | None:
        """Run ``fn`` only if a decoder is idle and nobody waits; None otherwise."""
        if self._running >= self.workers or self._waiting or self._slots.locked():
            return None
        await self._slots.acquire()
        return await self._on_slot(fn, *args, **kwargs)

    async def _on_slot(self, fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
        self._running += 1
        try:
            loop = asyncio.get_running_loop()
            return await loop.run_in_executor(
                self._executor, functools.partial(fn, *args, **kwargs)
            )
        finally:
            self._running -= 1
            self._slots.release()

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)
