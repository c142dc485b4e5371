"""A recording cut short (no summary: a crash, or stopped at the disk budget) is listed by a
scan that counts its messages without keeping them: a 2 GiB one stopped at the budget once
took a live console's 20 GB of memory when the page listed the recordings."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

from server.recorder.index import FlightIndex
from server.recorder.mcapfile import FlightFile, read_recording

MESSAGES = 2000
PAD = "x" * 20_000  # 40 MB of messages in all, a few hundred KB on disk (zstd)


def _cut_short(directory: Path) -> Path:
    path = directory / "20261126T112830Z.mcap"
    f = FlightFile(path, path.stem, 1, chunk_size=256 * 1024)
    for i in range(MESSAGES):
        f.write("/x", "vendor/Thing", 10 + i, {"i": i, "pad": PAD})
    f.abandon()  # as the recorder leaves a file stopped at the budget
    return path


def test_a_recording_without_summary_is_listed_in_bounded_memory(tmp_path: Path) -> None:
    path = _cut_short(tmp_path)
    assert path.stat().st_size < 5_000_000
    index = FlightIndex(tmp_path, budget_bytes=1 << 30)
    tracemalloc.start()
    try:
        rows = index.listing()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # everything up to the last finished chunk (the unfinished one is lost, as after a crash)
    assert [r.id for r in rows] == [path.stem]
    assert rows[0].messages == read_recording(path, strict=False).message_count
    assert MESSAGES - 50 < rows[0].messages < MESSAGES and rows[0].started is not None
    assert peak < 8_000_000, peak  # the messages alone are 40 MB


def test_the_count_only_scan_agrees_with_the_full_read(tmp_path: Path) -> None:
    path = _cut_short(tmp_path)
    full = read_recording(path, strict=False)
    counted = read_recording(path, strict=False, keep_messages=False)
    assert counted.messages == [] and len(full.messages) == full.message_count
    assert counted.message_count == full.message_count > MESSAGES - 50
    assert (counted.start_ns, counted.end_ns) == (full.start_ns, full.end_ns)
    assert counted.start_ns == 10 and counted.end_ns == 9 + full.message_count
    assert counted.topics == full.topics and counted.stopped is not None
