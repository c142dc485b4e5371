"""The decoder pool: bounded parallelism, back-pressure, interims only on an idle decoder."""

from __future__ import annotations

import asyncio
import threading

import pytest

from server.speech.errors import Busy
from server.speech.pool import DecoderPool
from tests.support.polling import until_async


async def test_at_most_workers_run_and_the_queue_is_bounded() -> None:
    pool = DecoderPool(workers=2, queue=2)
    gate = threading.Event()
    running = 0
    peak = 0
    lock = threading.Lock()

    def job(i: int) -> int:
        nonlocal running, peak
        with lock:
            running += 1
            peak = max(peak, running)
        gate.wait(5)
        with lock:
            running -= 1
        return i

    tasks = [asyncio.create_task(pool.run(job, i)) for i in range(4)]
    await until_async(lambda: pool.load == (2, 2), 10.0, "two running, two queued")
    with pytest.raises(Busy, match="busy"):
        await pool.run(job, 99)  # a fifth: refused at once, not queued
    assert await pool.try_run(job, 98) is None  # interims never queue
    gate.set()
    assert sorted(await asyncio.gather(*tasks)) == [0, 1, 2, 3]
    assert peak == 2 and pool.refused == 1
    assert await pool.try_run(job, 7) == 7  # idle again: an interim runs
    pool.close()


async def test_a_failing_job_frees_its_slot() -> None:
    pool = DecoderPool(workers=1, queue=0)

    def boom() -> None:
        raise RuntimeError("decoder failed")

    with pytest.raises(RuntimeError):
        await pool.run(boom)
    assert pool.load == (0, 0)
    assert await pool.run(lambda: 5) == 5
    pool.close()


def test_bad_sizes() -> None:
    with pytest.raises(ValueError):
        DecoderPool(0, 1)
