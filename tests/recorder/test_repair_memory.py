"""A recording a crash left without its footer is rewritten at start message by message: memory
stays bounded whatever the file's size (recordings reach 2 GiB; held whole, the repair of one
would take the console's memory at start-up)."""

from __future__ import annotations

import random
import tracemalloc
from pathlib import Path

from server.recorder.index import FlightIndex
from server.recorder.mcapfile import FlightFile, read_recording

MESSAGES = 2000
PAD_BYTES = 10_000  # random, as hex: 40 MB of messages in all, over 20 MB on disk (zstd)
PEAK_BYTES = 8_000_000  # a few chunks of the reader and the writer; the messages alone are 40 MB


def _record(path: Path) -> FlightFile:
    """A recording of incompressible messages (seeded), not finished yet."""
    rng = random.Random(7)
    f = FlightFile(path, path.stem, 1, chunk_size=256 * 1024)
    for i in range(MESSAGES):
        f.write("/x", "vendor/Thing", 10 + i, {"i": i, "pad": rng.randbytes(PAD_BYTES).hex()})
    return f


def _crashed(directory: Path) -> Path:
    path = directory / "20261126T142830Z.mcap"
    _record(path).abandon()  # no summary, no footer: as a kill -9 leaves it
    assert path.stat().st_size > 20_000_000
    return path


def test_a_crash_cut_recording_is_repaired_in_bounded_memory(tmp_path: Path) -> None:
    path = _crashed(tmp_path)
    before = read_recording(path, strict=False, keep_messages=False)
    assert not before.complete and before.message_count > MESSAGES - 50
    index = FlightIndex(tmp_path, budget_bytes=1 << 30)
    tracemalloc.start()
    try:
        assert index.repair(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < PEAK_BYTES, peak
    after = read_recording(path)  # strict: complete, footer and all
    assert after.complete and after.message_count == before.message_count
    assert [m.log_time_ns for m in after.messages] == list(range(10, 10 + before.message_count))
    assert [c for _ch, _t, c in after.decoded()][-1]["i"] == before.message_count - 1
    end = after.metadata["flight_end"]
    assert end["messages"] == str(before.message_count)
    assert end["repaired"] == f"cut short at byte {before.good_until} of {before.size}"
    assert after.metadata["flight"]["id"] == path.stem


def test_a_complete_recording_is_checked_in_bounded_memory_and_left_alone(
    tmp_path: Path,
) -> None:
    path = tmp_path / "20261126T142831Z.mcap"
    _record(path).finish(10 + MESSAGES, ["uav1"])
    data = path.read_bytes()
    index = FlightIndex(tmp_path, budget_bytes=1 << 30)
    tracemalloc.start()
    try:
        assert not index.repair(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < PEAK_BYTES, peak
    assert path.read_bytes() == data
