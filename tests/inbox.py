"""Collecting what roslibpy delivers on its own thread, for tests that wait on it."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

TIMEOUT = 10.0


class Inbox:
    """Collects callback values from roslibpy's thread; ``wait`` blocks on a condition."""

    def __init__(self) -> None:
        self.items: list[Any] = []
        self._cv = threading.Condition()

    def __call__(self, item: Any) -> None:
        with self._cv:
            self.items.append(item)
            self._cv.notify_all()

    def wait(self, n: int = 1, timeout: float = TIMEOUT) -> list[Any]:
        return self.wait_until(lambda items: len(items) >= n, timeout, f"{n} messages")

    def wait_until(
        self, pred: Callable[[list[Any]], bool], timeout: float = TIMEOUT, what: str = ""
    ) -> list[Any]:
        with self._cv:
            ok = self._cv.wait_for(lambda: pred(self.items), timeout)
            items = list(self.items)
        assert ok, f"inbox: {what or 'condition'} not met in {timeout} s; got {len(items)}"
        return items
