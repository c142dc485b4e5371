"""Waiting, in tests, for a real server, process or simulator to reach a state.

Bounded by the wall clock: a condition that never holds fails with ``what`` after ``timeout``
seconds, however loaded the machine is until then; a condition that holds returns at once, so a
test never sleeps a fixed time to let something happen.
"""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

T = TypeVar("T")

PERIOD_S = 0.05
"""Between two looks at the condition: short against every timeout the tests use, long enough
that a look (an HTTP request, a database read) does not load a shared machine."""


def until(
    pred: Callable[[], T],
    timeout: float,
    what: str,
    *,
    period: float = PERIOD_S,
    ignore: tuple[type[BaseException], ...] = (),
) -> T:
    """``pred()`` until it returns something truthy (returned); fails naming ``what``.

    ``ignore``: exceptions that mean "not yet" (a server still starting refuses connections).
    """
    deadline = time.monotonic() + timeout
    last: Any = None
    while True:
        try:
            value = pred()
        except ignore as exc:
            last = exc
        else:
            if value:
                return value
            last = value
        if time.monotonic() >= deadline:
            raise AssertionError(f"{what}: not in {timeout} s; last: {last!r}")
        time.sleep(period)


async def until_async(
    pred: Callable[[], T | Awaitable[T]],
    timeout: float,
    what: str,
    *,
    period: float = PERIOD_S,
    ignore: tuple[type[BaseException], ...] = (),
) -> T:
    """``until`` inside an event loop: ``pred`` may be a plain or an async function, and the
    loop runs (the server or simulator under test with it) between two looks."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while True:
        try:
            value = pred()
            last = await value if inspect.isawaitable(value) else value
        except ignore as exc:
            last = exc
        else:
            if last:
                return last  # type: ignore[no-any-return]
        if time.monotonic() >= deadline:
            raise AssertionError(f"{what}: not in {timeout} s; last: {last!r}")
        await asyncio.sleep(period)


def wait_for(get: Callable[[], Any], pred: Callable[[Any], bool], timeout: float, what: str) -> Any:
    """``get()`` until ``pred`` holds for it (returned); fails naming ``what``."""
    box: list[Any] = []

    def held() -> bool:
        box[:] = [get()]
        return pred(box[0])

    try:
        until(held, timeout, what)
    except AssertionError:
        raise AssertionError(
            f"{what}: condition not met in {timeout} s; last: {box[0]!r}"
        ) from None
    return box[0]
