"""The recordings directory: one ``<id>.mcap`` per flight, listed oldest first, with a budget.

- Ids are the UTC start time, ``20261123T083512Z`` (``-2``, ``-3`` … on a clash): sortable,
  safe in a URL and a file name. Anything else asked for is "not found", never a path.
- ``GET /api/v1/flights`` rows (:class:`FlightInfo`) come from the file's summary (statistics
  and the ``flight``/``flight_end`` metadata the recorder writes) when it is complete, or from a
  tolerant scan when it is not; they are cached by size and modification time.
- Disk budget: when the recordings take more than ``budget_bytes``, the oldest are deleted
  first; the current recording never is (the recorder stops it instead, with an alert).
- Repair: a file a crash left without footer is rewritten, complete, from everything up to its
  last finished chunk (then Foxglove and any MCAP reader open it), message by message: memory
  stays bounded whatever the file's size.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import re
import threading
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from server.recorder.errors import CorruptRecording, FlightNotFound, RecorderError
from server.recorder.mcapfile import (
    LIBRARY,
    PROFILE,
    open_private,
    read_recording,
    stream_messages,
)
from server.recorder.sessions import drone_of

SUFFIX = ".mcap"
_ID = re.compile(r"^\d{8}T\d{6}Z(?:-\d+)?$")


def iso(ns: int | None) -> str | None:
    """Nanoseconds since the epoch as ISO 8601 UTC with milliseconds (None stays None)."""
    if ns is None:
        return None
    t = dt.datetime.fromtimestamp(ns / 1e9, tz=dt.UTC)
    return t.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def drones_of(topics: list[str]) -> list[str]:
    return sorted({d for t in topics if (d := drone_of(t)) is not None})


@dataclass(frozen=True)
class FlightInfo:
    """One row of ``GET /api/v1/flights``."""

    id: str
    started: str | None
    ended: str | None  # None while recording (or a crashed file not repaired yet)
    drones: list[str]
    bytes: int
    messages: int

    def as_json(self) -> dict[str, object]:
        return {
            "id": self.id,
            "started": self.started,
            "ended": self.ended,
            "drones": list(self.drones),
            "bytes": self.bytes,
            "messages": self.messages,
        }


class FlightIndex:
    """The recordings of one data directory (thread-safe)."""

    def __init__(self, directory: Path, budget_bytes: int) -> None:
        self.directory = directory
        self.budget_bytes = budget_bytes
        self._lock = threading.Lock()
        self._cache: dict[Path, tuple[tuple[int, int], FlightInfo]] = {}

    def ensure_dir(self) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):
            self.directory.chmod(0o700)

    def new_id(self, now_s: float) -> str:
        base = dt.datetime.fromtimestamp(now_s, tz=dt.UTC).strftime("%Y%m%dT%H%M%SZ")
        candidate, n = base, 1
        while (self.directory / f"{candidate}{SUFFIX}").exists():
            n += 1
            candidate = f"{base}-{n}"
        return candidate

    def path_for(self, flight_id: str) -> Path:
        """The file of ``flight_id``.

        Raises:
            FlightNotFound: not an id of this index, or no such file.
        """
        if not _ID.match(flight_id):
            raise FlightNotFound(f"no flight '{flight_id}'")
        path = self.directory / f"{flight_id}{SUFFIX}"
        if not path.is_file():
            raise FlightNotFound(f"no flight '{flight_id}'")
        return path

    def files(self) -> list[Path]:
        """Recording files, oldest first (ids sort by start time)."""
        if not self.directory.is_dir():
            return []
        found = [p for p in self.directory.iterdir() if p.suffix == SUFFIX and _ID.match(p.stem)]
        return sorted(found, key=_sort_key)

    def info(self, path: Path) -> FlightInfo:
        """The listing row of one file (cached while it is unchanged)."""
        st = path.stat()
        key = (st.st_size, st.st_mtime_ns)
        with self._lock:
            cached = self._cache.get(path)
        if cached is not None and cached[0] == key:
            return cached[1]
        info = _read_info(path, st.st_size)
        with self._lock:
            self._cache[path] = (key, info)
        return info

    def listing(self, current: FlightInfo | None = None) -> list[FlightInfo]:
        """Every recording, oldest first; ``current`` (being written) replaces its file's row."""
        out: list[FlightInfo] = []
        for path in self.files():
            if current is not None and path.stem == current.id:
                out.append(current)
                continue
            try:
                out.append(self.info(path))
            except (OSError, RecorderError):
                continue  # vanished, or unreadable: not a flight anyone can download
        return out

    def delete(self, flight_id: str, current_id: str | None) -> None:
        """Delete a recording.

        Raises:
            FlightNotFound: no such flight.
            RecorderError: it is the recording in progress.
        """
        path = self.path_for(flight_id)
        if flight_id == current_id:
            raise RecorderError(f"flight '{flight_id}' is being recorded; it ends after landing")
        path.unlink(missing_ok=True)
        with self._lock:
            self._cache.pop(path, None)

    def over_budget(self, current_id: str | None, current_bytes: int) -> tuple[list[str], bool]:
        """Delete the oldest recordings until all fit ``budget_bytes``.

        Returns:
            (deleted ids, whether the current recording alone is still over the budget).
        """
        deleted: list[str] = []
        others = [p for p in self.files() if p.stem != current_id]
        sizes = {p: _size(p) for p in others}
        total = sum(sizes.values()) + current_bytes
        for path in others:
            if total <= self.budget_bytes:
                break
            path.unlink(missing_ok=True)
            total -= sizes[path]
            deleted.append(path.stem)
        return deleted, current_id is not None and total > self.budget_bytes

    def repair(self, path: Path) -> bool:
        """Rewrite a file left without footer as a complete one; False if it was complete.

        Two passes, each holding one chunk at a time (recordings reach 2 GiB): a count-only
        scan finds the channels, the metadata and where the file stops; the rewrite then
        streams the messages up to there.

        Raises:
            CorruptRecording: it is not an MCAP file at all.
        """
        rec = read_recording(path, strict=False, keep_messages=False)
        if rec.complete:
            return False
        tmp = path.with_suffix(".repair")
        tmp.unlink(missing_ok=True)
        with open_private(tmp) as out:
            writer = Writer(out, compression=CompressionType.ZSTD)
            writer.start(profile=PROFILE, library=LIBRARY)
            for name, data in rec.metadata.items():
                writer.add_metadata(name, data)
            schema_ids: dict[tuple[str, str, bytes], int] = {}
            channel_ids: dict[int, int] = {}
            for ch in rec.channels.values():
                skey = (ch.type, ch.schema_encoding, ch.schema_data)
                if skey not in schema_ids:
                    schema_ids[skey] = writer.register_schema(*skey)
                channel_ids[ch.id] = writer.register_channel(
                    ch.topic, ch.message_encoding, schema_ids[skey]
                )
            for seq, m in enumerate(stream_messages(path)):
                writer.add_message(
                    channel_ids[m.channel], m.log_time_ns, m.data, m.log_time_ns, seq
                )
            writer.add_metadata(
                "flight_end",
                {
                    "ended_ns": str(rec.end_ns or _started_ns(rec.metadata) or 0),
                    "drones": ",".join(drones_of(list(rec.topics))),
                    "messages": str(rec.message_count),
                    "repaired": f"cut short at byte {rec.good_until} of {rec.size}",
                },
            )
            writer.finish()  # type: ignore[no-untyped-call]
        os.replace(tmp, path)
        return True


def _sort_key(path: Path) -> tuple[str, int]:
    stem, _, n = path.stem.partition("-")
    return stem, int(n or 1)


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _started_ns(meta: dict[str, dict[str, str]]) -> int | None:
    raw = meta.get("flight", {}).get("started_ns")
    return int(raw) if raw and raw.isdigit() else None


def _read_info(path: Path, size: int) -> FlightInfo:
    meta: dict[str, dict[str, str]] = {}
    messages = 0
    first = last = None
    complete = False
    try:
        with path.open("rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is not None and summary.statistics is not None:
                stats = summary.statistics
                messages = stats.message_count
                first, last = stats.message_start_time, stats.message_end_time
                meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
                complete = True
    except Exception:  # any reader failure: scan the file tolerantly below
        complete = False
    if not complete:
        rec = read_recording(path, strict=False, keep_messages=False)
        meta, messages = rec.metadata, rec.message_count
        first, last = rec.start_ns, rec.end_ns
        drones = drones_of(list(rec.topics))
        ended = None
    else:
        end = meta.get("flight_end", {})
        drones = [d for d in end.get("drones", "").split(",") if d]
        ended_raw = end.get("ended_ns", "")
        ended = int(ended_raw) if ended_raw.isdigit() else last
    started = _started_ns(meta) or first
    return FlightInfo(path.stem, iso(started), iso(ended), drones, size, messages)


__all__ = ["CorruptRecording", "FlightIndex", "FlightInfo", "FlightNotFound", "iso"]
