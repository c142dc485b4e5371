"""Grammar gaps: transcripts Whisper heard plainly that the grammars could not read whole.

Such a transcript is not a mishearing but a way of saying a command the grammars do not know
yet ("hover for now and tell me your battery level"); the snap then bends it towards a sentence
they know, which is a guess. Each one is appended to a JSONL file in the data directory, so the
grammars (grammars/*.xml) can be widened from what operators actually say. The file is
bounded: past ``max_bytes`` it is moved to ``NAME.1`` (replacing the one before) and a new one
begins, so at most twice ``max_bytes`` are kept.
"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path
from typing import Any

from server.speech.recognizer import Recognition

log = logging.getLogger("uav_console.speech")

FILE_NAME = "speech-gaps.jsonl"
MAX_BYTES = 256 * 1024  # ~1 000 lines of ~250 bytes
MAX_TEXT = 500  # characters kept of a transcript (64 tokens is far less)


def entry(rec: Recognition, now: float) -> dict[str, Any]:
    """The JSON line for one recognition with a gap."""
    return {
        "t": round(now, 3),
        "heard": rec.gap[:MAX_TEXT],
        "asr_confidence": round(rec.asr_confidence, 3),
        "chosen": rec.text[:MAX_TEXT],
        "commands": rec.commands,
        "confidence": round(rec.confidence, 3),
    }


class GapLog:
    """Appends grammar gaps to ``path`` (thread-safe; call it off the event loop)."""

    def __init__(self, path: Path, max_bytes: int = MAX_BYTES) -> None:
        self.path = path
        self.max_bytes = max_bytes
        self._lock = threading.Lock()

    def record(self, rec: Recognition, now: float) -> bool:
        """Append ``rec`` if it holds a gap; whether a line was written. A file that cannot
        be written is logged, never raised: speech keeps working without its gap log."""
        if not rec.gap:
            return False
        line = json.dumps(entry(rec, now), ensure_ascii=False, default=str) + "\n"
        with self._lock:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                if self.path.exists() and self.path.stat().st_size + len(line) > self.max_bytes:
                    self.path.replace(self.path.with_name(self.path.name + ".1"))
                with self.path.open("a", encoding="utf-8") as f:
                    f.write(line)
            except OSError as exc:
                log.warning("grammar gap not logged to %s: %s", self.path, exc)
                return False
        return True

    def read(self) -> list[dict[str, Any]]:
        """Every entry kept, oldest first (the rotated file first)."""
        out: list[dict[str, Any]] = []
        for path in (self.path.with_name(self.path.name + ".1"), self.path):
            try:
                lines = path.read_text(encoding="utf-8").splitlines()
            except OSError:  # none yet, or not a file
                continue
            for text in lines:
                try:
                    item = json.loads(text)
                except json.JSONDecodeError:  # a line cut short by a crash: skipped
                    continue
                if isinstance(item, dict):
                    out.append(item)
        return out
