"""Throttling and queueing of one client's subscription to one topic, as rosbridge_suite does it.

rosbridge_library ``internal/subscribers`` + ``message_handlers.py`` (and protocols.md):

- ``queue_length == 0`` and ``throttle_rate == 0``: every message goes out at once.
- ``queue_length == 0`` and ``throttle_rate > 0`` (ThrottleMessageHandler): a message is sent if
  at least ``throttle_rate`` ms passed since the last one sent, otherwise dropped.
- ``queue_length > 0`` (QueueMessageHandler): messages enter a deque of that length that drops
  its oldest; it is drained one message per ``throttle_rate`` window (all at once when 0).

Several subscriptions of one client to one topic (same spelling) share one stream
(``subscribe.py`` ``update_params``): the smallest throttle rate, the smallest queue length, the
smallest fragment size, and compression cbor-raw > cbor > png > none.
Time is passed in; nothing here reads a clock.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class SubParams:
    throttle_rate_ms: int = 0
    queue_length: int = 0
    fragment_size: int | None = None
    compression: str = "none"


_COMPRESSION_RANK = {"none": 0, "png": 1, "cbor": 2, "cbor-raw": 3}


def merge(params: list[SubParams]) -> SubParams:
    """The shared stream's parameters for several subscriptions (rosbridge ``update_params``)."""
    if not params:
        return SubParams()
    frags = [p.fragment_size for p in params if p.fragment_size is not None]
    return SubParams(
        throttle_rate_ms=min(p.throttle_rate_ms for p in params),
        queue_length=min(p.queue_length for p in params),
        fragment_size=min(frags) if frags else None,
        compression=max((p.compression for p in params), key=lambda c: _COMPRESSION_RANK[c]),
    )


class TopicStream:
    """Delivery of one topic (as the client spelled it) to one client."""

    def __init__(self, topic: str, type_name: str) -> None:
        self.topic = topic
        self.type_name = type_name
        self.subs: dict[str | None, SubParams] = {}
        self.params = SubParams()
        self._queue: collections.deque[Any] = collections.deque()
        self._last_sent: float | None = None
        self.dropped = 0

    def add(self, sub_id: str | None, params: SubParams) -> None:
        self.subs[sub_id] = params
        self._update()

    def remove(self, sub_id: str | None) -> bool:
        """Remove one subscription (all when ``sub_id`` is None); True if any was removed."""
        if sub_id is None:
            found = bool(self.subs)
            self.subs.clear()
        else:
            found = self.subs.pop(sub_id, None) is not None
        self._update()
        return found

    def _update(self) -> None:
        self.params = merge(list(self.subs.values()))
        maxlen = max(1, self.params.queue_length)
        if self._queue.maxlen != maxlen:
            self._queue = collections.deque(list(self._queue)[-maxlen:], maxlen=maxlen)

    @property
    def empty(self) -> bool:
        return not self.subs

    def _window_s(self) -> float:
        return self.params.throttle_rate_ms / 1000.0

    def offer(self, msg: Any, now: float) -> list[Any]:
        """A message arrived from the graph; return those to send now."""
        if self.params.queue_length == 0:
            if self.params.throttle_rate_ms == 0:
                self._last_sent = now  # MessageHandler records every send (kept on transition)
                return [msg]
            if self._last_sent is None or now - self._last_sent >= self._window_s():
                self._last_sent = now
                return [msg]
            self.dropped += 1
            return []
        if len(self._queue) == self._queue.maxlen:
            self.dropped += 1
        self._queue.append(msg)
        return self.poll(now)

    def poll(self, now: float) -> list[Any]:
        """Drain what the queue may send at ``now``."""
        if not self._queue:
            return []
        if self.params.throttle_rate_ms == 0:
            out = list(self._queue)
            self._queue.clear()
            self._last_sent = now
            return out
        if self._last_sent is None or now - self._last_sent >= self._window_s():
            self._last_sent = now
            return [self._queue.popleft()]
        return []

    def next_due(self) -> float | None:
        """When :meth:`poll` will next have something to send (None: nothing queued)."""
        if not self._queue:
            return None
        if self._last_sent is None:
            return 0.0
        return self._last_sent + self._window_s()
