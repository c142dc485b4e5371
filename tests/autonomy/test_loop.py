"""Clocks, timing statistics, and the 100 Hz thread with its stall watchdog.

The thread tests run in real time (that is what they test) but never sleep: they wait on events
the loop sets, with generous timeouts.
"""

from __future__ import annotations

import os
import threading

import pytest

from drone.control.clock import MonotonicClock, VirtualClock
from drone.control.errors import GainError, LoopStateError
from drone.control.loop import ROOM_POLL_S, ControlLoop, TimingRecorder, room_wait_s


def test_virtual_clock_only_moves_forward() -> None:
    c = VirtualClock(5.0)
    assert c.now() == 5.0
    assert c.advance(0.25) == 5.25
    c.set(6.0)
    assert c.now() == 6.0
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            c.advance(bad)
    with pytest.raises(ValueError):
        c.set(1.0)
    a = MonotonicClock().now()
    assert MonotonicClock().now() >= a


def test_timing_recorder_statistics_from_known_ticks() -> None:
    rec = TimingRecorder(0.01, window=100)
    t = 0.0
    for k in range(100):
        late = 0.002 if k == 50 else 0.0001
        rec.record(t + late, t, 0.0005)
        t += 0.01
    s = rec.stats()
    assert s.ticks == 100
    assert s.period_p50_s == pytest.approx(0.01, abs=1e-9)
    assert s.rate_hz == pytest.approx(100.0)
    assert s.period_error_max_s == pytest.approx(0.0019, abs=1e-9)  # 1.9 ms early/late pair
    assert s.period_error_p50_s == pytest.approx(0.0, abs=1e-9)
    assert s.step_p50_s == pytest.approx(0.0005)


def test_bad_loop_parameters() -> None:
    with pytest.raises(GainError):
        ControlLoop(lambda now, dt: None, period_s=0.0)
    with pytest.raises(GainError):
        ControlLoop(lambda now, dt: None, period_s=0.01, spin_s=0.02)
    with pytest.raises(GainError):
        ControlLoop(lambda now, dt: None, period_s=0.01, stall_s=0.005)
    for bad in (-1, 100):
        with pytest.raises(GainError):
            ControlLoop(lambda now, dt: None, realtime_priority=bad)


def _run_a_few_ticks(**options: object) -> ControlLoop:
    """A loop with ``options`` started, ticked 5 times and stopped; checks what the OS says of
    its control thread's scheduling against what the loop reports."""
    ticked = threading.Event()
    threads: list[int] = []

    def step(now: float, dt: float) -> None:
        threads.append(threading.get_native_id())
        if len(threads) >= 5:
            ticked.set()

    loop = ControlLoop(step, **options)  # type: ignore[arg-type]
    loop.start()
    try:
        assert ticked.wait(5.0)
        policy = os.sched_getscheduler(threads[0])
        assert policy == (
            os.SCHED_FIFO if loop.scheduling.startswith("SCHED_FIFO") else os.SCHED_OTHER
        )
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # this thread was not changed
    finally:
        loop.stop()
    return loop


def test_the_control_thread_asks_for_real_time_scheduling_and_says_what_it_got() -> None:
    """Granted (root, CAP_SYS_NICE) → SCHED_FIFO on the control thread alone; refused → said."""
    loop = _run_a_few_ticks(realtime_priority=5, yield_while_spinning=False)
    s = loop.stats()
    assert s.scheduling == loop.scheduling
    assert s.scheduling == "SCHED_FIFO 5" or s.scheduling.startswith("normal (SCHED_FIFO 5 refused")
    assert ControlLoop(lambda now, dt: None).stats().scheduling == "normal"  # not asked


def test_room_between_ticks_for_gil_holding_work() -> None:
    """Work that holds the GIL (a video decode) starts only where it ends before the control
    thread wakes: 10 ms period, 2 ms spin, next wake at t = 10 ms."""
    args = {"next_wake": 0.010, "spin_s": 0.002, "period_s": 0.01}
    assert room_wait_s(0.002, in_tick=False, need_s=0.004, **args) == 0.0  # ends at 6 ms
    assert room_wait_s(0.006, in_tick=False, need_s=0.004, **args) == 0.0  # ends at 10 ms
    # ends after the wake: wait until the tick is under way (10 ms + 2 ms spin), then re-check
    assert room_wait_s(0.007, in_tick=False, need_s=0.004, **args) == pytest.approx(0.005)
    assert room_wait_s(0.011, in_tick=True, need_s=0.004, **args) == ROOM_POLL_S  # tick runs
    # work longer than a gap between ticks is not held back for ever: right after a tick
    # (step done at 10.5 ms, next wake at 18 ms) it fits, as it would in any fresh gap
    after = {"next_wake": 0.018, "spin_s": 0.002, "period_s": 0.01}
    assert room_wait_s(0.0105, in_tick=False, need_s=0.5, **after) == 0.0


def test_wait_for_room_is_a_no_op_unless_the_loop_runs() -> None:
    loop = ControlLoop(lambda now, dt: None)
    assert loop.wait_for_room(0.004) == 0.0  # not started
    waited: list[float] = []
    ticked = threading.Event()

    def step(now: float, dt: float) -> None:
        waited.append(loop.wait_for_room(0.004))  # asked on the control thread itself
        ticked.set()

    loop = ControlLoop(step)
    loop.start()
    try:
        assert ticked.wait(5.0)
    finally:
        loop.stop()
    assert waited[0] == 0.0
    assert loop.wait_for_room(0.004) == 0.0  # stopped


def test_a_refused_real_time_request_keeps_the_loop_running(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)  # what an unprivileged user gets
    loop = _run_a_few_ticks(realtime_priority=5)
    assert loop.scheduling == "normal (SCHED_FIFO 5 refused: [Errno 1] Operation not permitted)"


def test_the_thread_runs_at_100_hz_with_absolute_deadlines() -> None:
    done = threading.Event()
    stamps: list[float] = []

    def step(now: float, dt: float) -> None:
        stamps.append(now)
        if len(stamps) == 50:
            done.set()

    loop = ControlLoop(step, period_s=0.01)
    loop.start()
    try:
        assert done.wait(5.0)
    finally:
        loop.stop()
    s = loop.stats()
    assert s.ticks >= 50
    # 49 periods after the first tick: absolute deadlines do not drift even on a busy machine
    span = stamps[49] - stamps[0]
    assert span == pytest.approx(0.49, abs=0.05 + 0.01 * s.overruns)
    assert 80.0 < s.rate_hz < 120.0
    with pytest.raises(LoopStateError):
        loop.start()


def test_watchdog_hovers_when_the_step_stalls() -> None:
    release, stalled, entered = threading.Event(), threading.Event(), threading.Event()
    calls = {"n": 0}

    def step(now: float, dt: float) -> None:
        calls["n"] += 1
        if calls["n"] == 5:
            entered.set()
            release.wait(5.0)  # the step hangs (e.g. a blocked driver call)

    loop = ControlLoop(step, period_s=0.01, on_stall=stalled.set, stall_s=0.2)
    loop.start()
    try:
        assert entered.wait(5.0)
        assert stalled.wait(5.0)  # told to hover while the step is still stuck
        assert loop.stats().stalls == 1
    finally:
        release.set()
        loop.stop()
    assert loop.stats().overruns >= 15  # the ~0.2 s hang skipped ticks instead of bunching them


def test_a_failing_step_is_counted_and_the_loop_keeps_running() -> None:
    ok = threading.Event()
    calls = {"n": 0}

    def step(now: float, dt: float) -> None:
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("boom")
        if calls["n"] == 6:
            ok.set()

    loop = ControlLoop(step)
    loop.start()
    try:
        assert ok.wait(5.0)
    finally:
        loop.stop()
    assert loop.errors == 1 and "boom" in (loop.last_error or "")
