"""Decodes shared by identical audio: a final utterance whose speech is exactly what an interim
(while-speaking) decode already has, or is now, decoding waits for that result instead of
decoding it again.

Why: the encoder's ~0.5 s over Whisper's fixed window is most of the time from the end of speech
to the command (bench/speech.py). An operator stops speaking a moment before releasing the
button, and hands-free waits for 0.7 s of silence; the stream decodes speculatively as soon as
its voice detector hears the silence start (server.speech.stream), so by the time the utterance
ends the decode is done or under way. The key is a digest of the speech samples the recogniser
would decode (after its VAD trim), the guidance and the dialog state, so a reuse is exactly the
result a fresh decode would give (decoding is deterministic: greedy, temperature 0).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from concurrent.futures import Future
from typing import Generic, TypeVar

import numpy as np

T = TypeVar("T")


def digest(samples: np.ndarray) -> bytes:
    """A 128-bit digest of the samples' values and length (BLAKE2b; ~0.1 ms per 10 s)."""
    data = np.ascontiguousarray(samples, dtype=np.float32)
    return hashlib.blake2b(data.tobytes(), digest_size=16).digest()


class SharedResults(Generic[T]):
    """At most ``size`` recent results (or results being computed), by key; thread-safe."""

    def __init__(self, size: int = 8) -> None:
        if size < 1:
            raise ValueError("a result memo needs room for at least one result")
        self.size = size
        self._items: OrderedDict[Hashable, Future[T]] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0  # calls answered by an earlier (or still running) computation

    def get(self, key: Hashable, compute: Callable[[], T]) -> tuple[T, bool]:
        """``(value, reused)``: the result for ``key``, computed by ``compute()`` unless an
        earlier call has it or is computing it (then this call waits for that one). A failed
        computation raises in every waiter and is forgotten, so the next call computes afresh.
        """
        with self._lock:
            future = self._items.get(key)
            owner = future is None
            if future is None:
                future = Future()
                self._items[key] = future
                while len(self._items) > self.size:
                    self._items.popitem(last=False)
            else:
                self._items.move_to_end(key)
                self.hits += 1
        if not owner:
            return future.result(), True
        try:
            value = compute()
        except BaseException as exc:
            with self._lock:
                if self._items.get(key) is future:
                    del self._items[key]
            future.set_exception(exc)
            raise
        future.set_result(value)
        return value, False
