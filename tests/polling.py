"""Waiting, in tests, for a real server or simulator to reach a state (wall clock, bounded)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def wait_for(get: Callable[[], Any], pred: Callable[[Any], bool], timeout: float, what: str) -> Any:
    """``get()`` every 50 ms until ``pred`` holds for it (returned); fails naming ``what``."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while time.monotonic() < deadline:
        last = get()
        if pred(last):
            return last
        time.sleep(0.05)
    raise AssertionError(f"{what}: condition not met in {timeout} s; last: {last!r}")
