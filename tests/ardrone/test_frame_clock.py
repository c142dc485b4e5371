"""FrameClock: PaVE timestamps (drone ms) to capture times on the host's clock."""

from __future__ import annotations

import random
import statistics

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drone.ardrone.frame_clock import FrameClock

OFFSET_S = 1234.5  # host clock minus drone clock
LEAST_DELAY_S = 0.030


def wifi_frames(n: int, seed: int, start_ms: int = 5000) -> list[tuple[int, float, float]]:
    """(timestamp_ms, capture on the host clock, received) at 15 fps with a jittery link."""
    rng = random.Random(seed)
    out = []
    for i in range(n):
        ts = start_ms + round(i * 1000 / 15)
        capture = ts / 1000 + OFFSET_S
        out.append((ts, capture, capture + LEAST_DELAY_S + rng.expovariate(1 / 0.040)))
    return out


def test_capture_time_is_recovered_without_the_links_jitter() -> None:
    clock = FrameClock(window_s=10.0)
    frames = wifi_frames(600, seed=1)  # 40 s
    errors = [clock.stamp(ts, rx) - capture for ts, capture, rx in frames]
    settled = errors[30:]  # after two seconds the window holds a near-least delay
    assert all(LEAST_DELAY_S <= e < LEAST_DELAY_S + 0.006 for e in settled), max(settled)
    # A fixed "received − 50 ms" guess is wrong by the jitter: tens of ms either way.
    fixed = [rx - 0.050 - capture for _, capture, rx in frames[30:]]
    assert statistics.pstdev(fixed) > 0.030 > statistics.pstdev(settled) * 10


@given(
    delays=st.lists(st.floats(0.0, 2.0), min_size=1, max_size=60),
    offset=st.floats(-1e6, 1e6),
    window=st.floats(0.1, 30.0),
)
def test_stamp_lies_between_capture_and_receipt(
    delays: list[float], offset: float, window: float
) -> None:
    clock = FrameClock(window_s=window)
    for i, delay in enumerate(delays):
        ts = 1000 + 50 * i
        capture = ts / 1000 + offset
        stamp = clock.stamp(ts, capture + delay)
        assert capture - 1e-6 <= stamp <= capture + delay + 1e-6


def test_a_drone_reboot_restarts_the_estimate() -> None:
    clock = FrameClock()
    for ts, _, rx in wifi_frames(150, seed=2, start_ms=900_000):
        clock.stamp(ts, rx)
    # The drone restarts: its clock begins again near 0 and the host has moved on 20 s.
    later = 900_000 / 1000 + 150 / 15 + 20.0
    ts, rx = 40, OFFSET_S + later + 0.045
    capture = rx - 0.045
    assert clock.stamp(ts, rx) == pytest.approx(rx)  # first frame of the new clock
    assert clock.resets == 1
    assert clock.stamp(ts + 66, capture + 0.066 + 0.031) == pytest.approx(capture + 0.066 + 0.031)


def test_window_follows_clock_drift() -> None:
    clock = FrameClock(window_s=5.0)
    errors = []
    for i in range(15 * 120):  # two minutes with the drone's clock 200 ppm slow
        t = i / 15
        ts = round(t * (1 - 200e-6) * 1000)
        capture = t + OFFSET_S
        errors.append(clock.stamp(ts, capture + LEAST_DELAY_S) - capture)
    assert max(abs(e - LEAST_DELAY_S) for e in errors) < 0.002  # 2 ms: the ms rounding plus drift


@pytest.mark.parametrize("window", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_window_is_a_value_error(window: float) -> None:
    with pytest.raises(ValueError, match="window_s"):
        FrameClock(window_s=window)
