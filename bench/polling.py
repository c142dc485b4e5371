"""Waiting in benchmarks: poll until a condition holds, a server's errors meanwhile tolerated."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import Any

import httpx


def wait_for(fn: Callable[[], Any], what: str, timeout: float = 30.0, period: float = 0.05) -> Any:
    """``fn()``'s first truthy result within ``timeout`` seconds; an HTTP error or a reply not
    shaped yet (KeyError, ValueError, TypeError) counts as not yet.

    Raises:
        RuntimeError: ``what`` did not happen in time.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError, KeyError, ValueError, TypeError):
            out = fn()
            if out:
                return out
        time.sleep(period)
    raise RuntimeError(f"timed out waiting for {what}")
