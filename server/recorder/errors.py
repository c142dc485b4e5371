"""Errors of the flight recorder.

RecorderError
├── FlightNotFound     no recording with that id
├── CorruptRecording   a file is not a readable MCAP; ``offset`` is where reading stopped
└── RecordingStopped   the writer gave up (disk full, budget reached, I/O error)
"""

from __future__ import annotations


class RecorderError(Exception):
    """Base of the recorder's errors."""


class FlightNotFound(RecorderError):
    pass


class CorruptRecording(RecorderError):
    """Raised with the byte ``offset`` at which the file stopped making sense."""

    def __init__(self, path: str, offset: int, why: str) -> None:
        super().__init__(f"{path}: {why} at byte offset {offset}")
        self.path = path
        self.offset = offset
        self.why = why


class RecordingStopped(RecorderError):
    pass
