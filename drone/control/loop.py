"""The 100 Hz control thread with absolute deadlines, timing statistics and a stall watchdog.

Deadlines are absolute (``t0 + k·period``), so errors never accumulate into drift. Each wait
sleeps until ``spin_s`` before the deadline and then spins (``time.sleep(0)`` yields the GIL) for
sub-millisecond accuracy: ``time.sleep`` alone wakes 50–1000 µs late on Linux under load
(bench/autonomy.py measures both; ``spin_s=0`` gives the plain-sleep loop). A step that finishes
after the *next* deadline is an overrun; missed ticks are skipped, not bunched up.

In a vehicle process (``serve``'s default) the loop is also told to hold the GIL while it spins
(``yield_while_spinning=False``: the deadline is met by the thread that already holds it, not by
one that waits up to ``sys.getswitchinterval()`` for it; a thread that has waited that long can
still take it over, so a vehicle process shortens the interval to 0.1 ms; its other threads give
up ≤ ``spin_s`` = 2 ms of every 10 ms for it — 1 ms was too short where the GIL's holder is
itself preempted on a loaded CPU: p99 period error 0.96 ms against 0.17 ms with 2 ms, 3 busy
processes on 2 cores and a busy thread at nice -10 in the loop's process) and to ask the OS for
real-time scheduling (``realtime_priority``: SCHED_FIFO, as PX4 runs its Linux control tasks),
which a loaded CPU cannot delay; where the OS refuses (not root, no CAP_SYS_NICE) it says so in
``scheduling`` and runs as before.

Work elsewhere in the process that holds the GIL for milliseconds without a break (libavcodec's
H.264 decode does: PyAV keeps the GIL through it) would still make a tick late if it began just
before the thread wakes. :meth:`ControlLoop.wait_for_room` lets such work wait for a gap between
ticks that is long enough for it: the control loop's time is shared out by appointment, as in a
time-triggered executive, not by preemption, which the GIL does not allow.

Watchdog (like ArduPilot's main-loop watchdog): a second thread checks that ticks keep coming; if
none has finished for ``stall_s`` (0.2 s) it calls ``on_stall`` once per stall (the vehicle
tells the driver to hover).

The step itself is a plain callable ``step(now, dt)`` (``now`` from the injected clock, by
default ``time.monotonic`` like the driver's event stamps; deadlines use ``perf_counter``); in
lockstep the rig calls the same callable on a virtual clock and this module is not involved.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from drone.control.errors import GainError, LoopStateError

log = logging.getLogger(__name__)

StepFn = Callable[[float, float], object]  # the return value is ignored
ROOM_POLL_S = 0.0002  # how often wait_for_room looks again while a tick is under way
STEP_ALLOWANCE_S = 0.001  # room left after a tick's spin for its step (step p50 ≈ 0.1 ms)


def thread_scheduling() -> str:
    """The calling thread's scheduling as ControlLoop.scheduling says it: "normal" for the
    default policy, else the policy and priority (e.g. "SCHED_RR 5", inherited from a vehicle
    process's main thread)."""
    try:
        policy = os.sched_getscheduler(0)
        priority = os.sched_getparam(0).sched_priority
    except (OSError, AttributeError):
        return "normal"
    names = {os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_RR: "SCHED_RR"}
    return f"{names[policy]} {priority}" if policy in names else "normal"


def room_wait_s(
    now: float, next_wake: float, in_tick: bool, need_s: float, spin_s: float, period_s: float
) -> float:
    """How long work needing ``need_s`` of the GIL should wait so that it ends before the
    control thread wakes at ``next_wake`` (0: start now). ``need_s`` is capped at the gap
    between two ticks, so work longer than that starts right after a tick instead."""
    need = min(need_s, period_s - spin_s - STEP_ALLOWANCE_S)
    if in_tick:
        return ROOM_POLL_S
    if now + need <= next_wake:
        return 0.0
    return max(ROOM_POLL_S, next_wake + spin_s - now)  # until the tick is under way


@dataclass(frozen=True)
class LoopStats:
    """Timing of the last ``window`` ticks (seconds). Period error = |period − nominal|."""

    rate_hz: float
    ticks: int
    overruns: int
    stalls: int
    period_p50_s: float
    period_error_p50_s: float
    period_error_p99_s: float
    period_error_max_s: float
    lateness_p99_s: float  # how late after its deadline a tick started
    step_p50_s: float  # time spent in the step itself
    step_max_s: float
    scheduling: str = "normal"  # what the OS granted the control thread (ControlLoop.scheduling)

    def as_dict(self) -> dict[str, float | int | str]:
        return dict(vars(self))


class TimingRecorder:
    """Ring buffers of tick periods, deadline lateness and step durations."""

    def __init__(self, period_s: float, window: int = 6000) -> None:
        self.period_s = period_s
        self._periods = np.zeros(window)
        self._late = np.zeros(window)
        self._steps = np.zeros(window)
        self._n = 0
        self.overruns = 0
        self.stalls = 0
        self._last_start: float | None = None

    def record(self, start: float, deadline: float, step_s: float) -> None:
        i = self._n % len(self._periods)
        if self._last_start is not None:
            self._periods[i] = start - self._last_start
        else:
            self._periods[i] = self.period_s
        self._late[i] = start - deadline
        self._steps[i] = step_s
        self._last_start = start
        self._n += 1

    def stats(self) -> LoopStats:
        n = min(self._n, len(self._periods))
        if n == 0:
            return LoopStats(0.0, 0, self.overruns, self.stalls, 0, 0, 0, 0, 0, 0, 0)
        p = self._periods[:n]
        err = np.abs(p - self.period_s)
        return LoopStats(
            rate_hz=float(1.0 / np.median(p)) if np.median(p) > 0 else 0.0,
            ticks=self._n,
            overruns=self.overruns,
            stalls=self.stalls,
            period_p50_s=float(np.median(p)),
            period_error_p50_s=float(np.median(err)),
            period_error_p99_s=float(np.percentile(err, 99)),
            period_error_max_s=float(err.max()),
            lateness_p99_s=float(np.percentile(self._late[:n], 99)),
            step_p50_s=float(np.median(self._steps[:n])),
            step_max_s=float(self._steps[:n].max()),
        )


class ControlLoop:
    """Run ``step(now, dt)`` every ``period_s`` in its own thread; see the module docstring."""

    def __init__(
        self,
        step: StepFn,
        *,
        period_s: float = 0.01,
        spin_s: float = 0.002,
        on_stall: Callable[[], None] | None = None,
        stall_s: float = 0.2,
        name: str = "control",
        clock: Callable[[], float] = time.monotonic,
        yield_while_spinning: bool = True,
        realtime_priority: int = 0,
    ) -> None:
        if not 0 < period_s <= 1.0:
            raise GainError(f"period_s must be in (0, 1], got {period_s!r}")
        if not 0 <= spin_s < period_s:
            raise GainError(f"spin_s must be in [0, period_s), got {spin_s!r}")
        if stall_s <= period_s:
            raise GainError("stall_s must exceed period_s")
        if not 0 <= realtime_priority <= 99:  # sched_get_priority_max(SCHED_FIFO) on Linux
            raise GainError(f"realtime_priority must be in [0, 99], got {realtime_priority!r}")
        self._step = step
        self._clock = clock  # what ``step`` receives as ``now`` (deadlines use perf_counter)
        self.yield_while_spinning = yield_while_spinning  # False: pure busy-wait, holds the GIL
        self.period_s = period_s
        self.realtime_priority = realtime_priority
        self.scheduling = "normal"  # what the OS granted the control thread
        self.spin_s = spin_s
        self.stall_s = stall_s
        self._on_stall = on_stall
        self._name = name
        self.timing = TimingRecorder(period_s)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._watchdog: threading.Thread | None = None
        self._last_tick_end = 0.0
        self._next_wake = 0.0  # when the control thread next wakes (perf_counter)
        self._in_tick = False  # from that wake until its step has run
        self.errors = 0
        self.last_error: str | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Start the control thread and the watchdog.

        Raises:
            LoopStateError: already started.
        """
        if self._thread is not None:
            raise LoopStateError("control loop already started")
        self._last_tick_end = time.perf_counter()
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._watchdog = threading.Thread(
            target=self._watch, name=f"{self._name}-watchdog", daemon=True
        )
        self._thread.start()
        self._watchdog.start()

    def stop(self, timeout: float = 1.0) -> None:
        """Stop both threads (idempotent)."""
        self._stop.set()
        for t in (self._thread, self._watchdog):
            if t is not None and t is not threading.current_thread():
                t.join(timeout)

    def stats(self) -> LoopStats:
        return replace(self.timing.stats(), scheduling=self.scheduling)

    def wait_for_room(self, need_s: float) -> float:
        """Block the calling thread until ``need_s`` of GIL-holding work can finish before the
        control thread next wakes (at most one period); returns how long it waited. A no-op on
        the control thread itself and when the loop is not running."""
        if not self.running or threading.current_thread() is self._thread:
            return 0.0
        t0 = time.perf_counter()
        limit = t0 + self.period_s
        while (now := time.perf_counter()) < limit:
            wait = room_wait_s(
                now, self._next_wake, self._in_tick, need_s, self.spin_s, self.period_s
            )
            if wait <= 0.0:
                break
            time.sleep(min(wait, limit - now))
        return time.perf_counter() - t0

    def _wait_until(self, deadline: float) -> None:
        self._next_wake = deadline - self.spin_s
        remaining = deadline - time.perf_counter() - self.spin_s
        if remaining > 0:
            time.sleep(remaining)
        self._in_tick = True
        if self.yield_while_spinning:
            while time.perf_counter() < deadline:
                time.sleep(0)  # yields the GIL (and the CPU) while spinning
        else:
            while time.perf_counter() < deadline:
                pass

    def _enter_realtime(self) -> None:
        """SCHED_FIFO at ``realtime_priority`` for the calling (control) thread, if permitted."""
        if self.realtime_priority <= 0:
            return
        asked = f"SCHED_FIFO {self.realtime_priority}"
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.realtime_priority))
        except (OSError, AttributeError) as exc:  # EPERM without privilege; not on macOS
            self.scheduling = f"{thread_scheduling()} ({asked} refused: {exc})"
            log.info("%s: control thread keeps %s", self._name, self.scheduling)
        else:
            self.scheduling = asked

    def _run(self) -> None:
        self._enter_realtime()
        period = self.period_s
        t0 = time.perf_counter()
        k = 1
        last = t0
        while not self._stop.is_set():
            deadline = t0 + k * period
            self._wait_until(deadline)
            start = time.perf_counter()
            try:
                self._step(self._clock(), start - last)
            except Exception as exc:  # a bad step must not kill the loop; counted and logged
                self.errors += 1
                self.last_error = repr(exc)
                log.exception("control step failed")
            end = time.perf_counter()
            self.timing.record(start, deadline, end - start)
            self._last_tick_end = end
            self._in_tick = False
            last = start
            k += 1
            next_deadline = t0 + k * period
            if end > next_deadline:  # overran: skip the ticks we can no longer make
                missed = int((end - next_deadline) // period) + 1
                self.timing.overruns += missed
                k += missed

    def _watch(self) -> None:
        stalled = False
        while not self._stop.wait(self.stall_s / 4):
            gap = time.perf_counter() - self._last_tick_end
            if gap > self.stall_s and not stalled:
                stalled = True
                self.timing.stalls += 1
                log.warning("control loop stalled for %.3f s: hovering", gap)
                if self._on_stall is not None:
                    try:
                        self._on_stall()
                    except Exception:
                        log.exception("on_stall failed")
            elif gap <= self.stall_s:
                stalled = False
