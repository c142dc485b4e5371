"""kill -9 while recording: everything up to the last finished chunk reads back."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from server.recorder.index import FlightIndex
from server.recorder.mcapfile import read_recording

ROOT = Path(__file__).resolve().parents[2]


def test_sigkill_loses_nothing_before_the_last_finished_chunk(tmp_path: Path) -> None:
    on_disk = 0
    with subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("crash_child.py")), str(tmp_path)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as child:
        try:
            assert child.stdout is not None and child.stderr is not None
            for line in child.stdout:
                on_disk = int(line.split()[1])
                if on_disk >= 2000:
                    break
            else:
                raise AssertionError(f"the child stopped: {child.stderr.read()}")
        finally:
            os.kill(child.pid, signal.SIGKILL)
            child.wait(10)
    (path,) = FlightIndex(tmp_path, 10**9).files()
    rec = read_recording(path, strict=False)
    assert not rec.complete
    ticks = [m["tm"] for _c, _t, m in rec.decoded()]
    assert len(ticks) >= on_disk  # all that was flushed before the kill (maybe a chunk more)
    assert ticks == [float(i) for i in range(len(ticks))]  # in order, none missing
