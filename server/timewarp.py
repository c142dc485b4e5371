"""A faster clock for a whole ``serve``: the console, its vehicle processes and their simulators
run ``N`` times faster than the wall clock (``serve --clock-speed N``, ``UAVC_CLOCK_SPEED``).

For tests and benchmarks: a live patrol through one or two handoffs (about ten simulated
minutes) takes a minute or two. It scales the process's monotonic clocks and sleeps before
anything else is imported (``python -m server`` installs it first), so every clock injected
as ``time.monotonic`` (the CTM, LTMs, task managers, the simulator, the 100 Hz control loop's
``perf_counter`` deadlines and ``time.sleep``) and asyncio's loop time (``loop.time()`` reads
``time.monotonic``; the selector's waits are divided by ``N``) run ``N`` times faster, alike in
the web process and in each vehicle process (which inherit the variable). The wall clock
(``time.time``) is left alone: command deadlines and stamps compare it with other machines'.
Threads' own timed waits (locks, events) stay in wall seconds; asyncio runs on its selector
loop (uvloop keeps its own clock).

Watchdogs on links (navdata silence, the console's heartbeat, an LTM's status) judge silence in
wall seconds (:func:`guard_s`). Every process does ``N`` times the work per wall second, so the
camera belongs off (``--no-camera``) and ``N`` within what the machine's cores sustain; the
simulator caps a stall at 0.5 simulated seconds, so an overloaded machine shows as a slower
run, not a jump.
"""

from __future__ import annotations

import math
import os
import selectors
import sys
import time
from collections.abc import Sequence
from typing import Any, SupportsIndex

ENV = "UAVC_CLOCK_SPEED"
FLAG = "--clock-speed"
MAX_SPEED = 100.0

_real_monotonic = time.monotonic
_real_perf_counter = time.perf_counter
_real_sleep = time.sleep
_speed = 1.0


class ClockSpeedError(ValueError):
    """A clock speed that is not a number in (0, MAX_SPEED]."""


def speed() -> float:
    """The installed speed (1.0: real time)."""
    return _speed


def parse(text: str) -> float:
    """``text`` as a clock speed.

    Raises:
        ClockSpeedError: not a number in (0, MAX_SPEED].
    """
    try:
        value = float(text)
    except ValueError:
        raise ClockSpeedError(f"clock speed must be a number, not {text!r}") from None
    if not (math.isfinite(value) and 0.0 < value <= MAX_SPEED):
        raise ClockSpeedError(f"clock speed must be in (0, {MAX_SPEED:g}], not {text}")
    return value


def requested(argv: Sequence[str], env: dict[str, str] | os._Environ[str]) -> str | None:
    """The speed asked for: ``--clock-speed N`` (or ``=N``) on the command line, else the
    environment's ``UAVC_CLOCK_SPEED``; None when neither."""
    for i, arg in enumerate(argv):
        if arg == FLAG and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(FLAG + "="):
            return arg.split("=", 1)[1]
    return env.get(ENV)


class _ScaledSelector(selectors.DefaultSelector):
    """asyncio's selector: a wait of ``t`` loop seconds is ``t / N`` wall seconds."""

    def select(self, timeout: float | None = None) -> list[tuple[Any, int]]:
        if timeout is not None and timeout > 0:
            timeout = timeout / _speed
        return super().select(timeout)


def guard_s(seconds: float) -> float:
    """A watchdog on a link (navdata, the console's heartbeat, an LTM's status) in clock
    seconds. The link's delays are the machine's, in wall seconds, so its silence is judged in
    wall seconds: at ``N``× a scheduling delay of 0.3 s would read as ``0.3 N`` s of silence
    and trip a 1 s watch that never trips in real time."""
    return seconds * _speed


def install(value: float) -> None:
    """Run this process's monotonic clocks, sleeps and asyncio loops ``value`` times faster
    (once, before anything captures ``time.monotonic``; 1.0 does nothing).

    Raises:
        ClockSpeedError: ``value`` outside (0, MAX_SPEED], or a second, different speed.
    """
    global _speed
    value = parse(str(value))
    if value == _speed:
        return
    if _speed != 1.0:
        raise ClockSpeedError(f"the clock already runs at {_speed:g}×")
    _speed = value
    m0, p0 = _real_monotonic(), _real_perf_counter()

    def monotonic() -> float:
        return m0 + (_real_monotonic() - m0) * value

    def perf_counter() -> float:
        return p0 + (_real_perf_counter() - p0) * value

    def monotonic_ns() -> int:
        return int(monotonic() * 1e9)

    def perf_counter_ns() -> int:
        return int(perf_counter() * 1e9)

    def sleep(seconds: float | SupportsIndex) -> None:
        _real_sleep(max(0.0, float(seconds)) / value)

    time.monotonic = monotonic
    time.perf_counter = perf_counter
    time.monotonic_ns = monotonic_ns
    time.perf_counter_ns = perf_counter_ns
    time.sleep = sleep
    selectors.DefaultSelector = _ScaledSelector  # type: ignore[misc]
    os.environ[ENV] = f"{value:g}"  # the vehicle processes it starts run at the same speed


def install_from(argv: Sequence[str], env: dict[str, str] | os._Environ[str]) -> None:
    """``python -m server``'s first step; a bad speed exits with status 2 and one line."""
    text = requested(argv, env)
    if text is None:
        return
    try:
        install(parse(text))
    except ClockSpeedError as exc:
        print(f"uav-console: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
