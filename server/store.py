"""The audit log: every utterance, its interpretation, the action taken and the outcome (SQLite).

Durability: WAL journal with ``synchronous=FULL``. In WAL mode NORMAL already survives a crash
of the *process* (a committed transaction is in the WAL file, which the OS keeps); FULL also
fsyncs the WAL on each commit, so entries survive a power loss or kernel panic too. An audit log
is written a few times per spoken sentence, so the fsync cost (~ms) is irrelevant, and "who
commanded what" is exactly what must not be lost when something goes wrong.
(SQLite docs, "Write-Ahead Logging" §2.3 and PRAGMA synchronous.)
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

SCHEMA = """
CREATE TABLE IF NOT EXISTS audit (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    time        REAL    NOT NULL,      -- seconds since the epoch (wall clock)
    role        TEXT    NOT NULL,      -- operator role: pilot, observer, system (ANS)
    source      TEXT    NOT NULL,      -- speech, text, rest, ans
    drone       TEXT    NOT NULL,
    utterance   TEXT    NOT NULL,
    confidence  REAL,
    commands    TEXT    NOT NULL,      -- JSON list of the interpreted commands
    action      TEXT    NOT NULL,      -- what the dialog manager did: executed, refused, asked, ...
    outcome     TEXT    NOT NULL,      -- the reply given, or the task result
    state       TEXT    NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS audit_time ON audit(time);
"""
# Added with the flight recorder: the id of the flight recording (GET /api/v1/flights) that
# holds what happened around the row ("" when nothing was being recorded).
RECORDING_COLUMN = "ALTER TABLE audit ADD COLUMN recording TEXT NOT NULL DEFAULT ''"


log = logging.getLogger(__name__)
T = TypeVar("T")


def _text(value: str) -> str:
    """``value`` storable as UTF-8: lone surrogates escaped (``\\ud800``). SQLite refuses
    them with UnicodeEncodeError, which is not a sqlite3.Error: an utterance holding one would
    fly the drone and leave no row."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return value.encode("utf-8", "backslashreplace").decode("utf-8")
    return value


class AuditError(Exception):
    """The audit log file cannot be opened or written (message says why)."""


@dataclass(frozen=True)
class AuditEntry:
    id: int
    time: float
    role: str
    source: str
    drone: str
    utterance: str
    confidence: float | None
    commands: list[dict[str, Any]]
    action: str
    outcome: str
    state: str
    recording: str = ""


class AuditLog:
    """Append-only SQLite audit log; safe to call from several threads."""

    def __init__(self, path: Path | str, clock: Callable[[], float] = time.time) -> None:
        """Open (creating if needed) the log at ``path`` (``":memory:"`` for tests).

        Raises:
            AuditError: the file cannot be opened or is not a usable database.
        """
        self.path = str(path)
        self._clock = clock
        # Returns the flight recording's id for a new row (set by the runtime when recording).
        self.recording: Callable[[], str] | None = None
        self._lock = threading.Lock()
        self._writer: ThreadPoolExecutor | None = None  # append_later's one thread (in order)
        try:
            if self.path != ":memory:":
                Path(self.path).parent.mkdir(parents=True, exist_ok=True)
                # Who said what is private: the log (and SQLite's -wal/-shm files, which copy
                # the database's mode) is readable by its owner only.
                os.close(os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600))
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.executescript(SCHEMA)
            columns = {r[1] for r in self._db.execute("PRAGMA table_info(audit)")}
            if "recording" not in columns:
                self._db.execute(RECORDING_COLUMN)
        except (sqlite3.Error, OSError) as exc:
            raise AuditError(f"cannot open audit log {self.path}: {exc}") from exc

    def append(
        self,
        *,
        utterance: str,
        commands: list[dict[str, Any]],
        action: str,
        outcome: str,
        role: str = "pilot",
        source: str = "text",
        drone: str = "uav1",
        confidence: float | None = None,
        state: str = "",
        now: float | None = None,
    ) -> int:
        """Append one entry (committed before returning); returns its id.

        Raises:
            AuditError: the write failed (disk full, file removed, ...).
        """
        row = (
            self._clock() if now is None else now,
            _text(role),
            _text(source),
            _text(drone),
            _text(utterance),
            confidence,
            _text(json.dumps(commands)),
            _text(action),
            _text(outcome),
            _text(state),
            self.recording() if self.recording is not None else "",
        )
        with self._lock:
            try:
                cur = self._db.execute(
                    "INSERT INTO audit (time, role, source, drone, utterance, confidence,"
                    " commands, action, outcome, state, recording)"
                    " VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                    row,
                )
            except sqlite3.Error as exc:
                raise AuditError(f"cannot write audit log {self.path}: {exc}") from exc
            return int(cur.lastrowid or 0)

    def append_later(self, **entry: Any) -> Future[int]:
        """:meth:`append` on the log's own writer thread, in call order; returns at once.

        For callers on the event loop whose command must reach the drone before the fsync of
        its audit row (a direct emergency or land: ``synchronous=FULL`` costs milliseconds,
        tens under load, and the driver sends from the same loop). A failed write is logged.
        """
        fut = self.in_order(lambda: self.append(**entry))
        fut.add_done_callback(_log_failure)
        return fut

    def in_order(self, write: Callable[[], T]) -> Future[T]:
        """``write()`` (rows written through this log) on the log's own writer thread, after
        every write handed to it before: rows written this way and by :meth:`append_later`
        keep the order they were asked in."""
        with self._lock:
            if self._writer is None:
                self._writer = ThreadPoolExecutor(1, thread_name_prefix="audit")
            writer = self._writer
        return writer.submit(write)

    def recent(self, limit: int = 50, drone: str | None = None) -> list[AuditEntry]:
        """The newest ``limit`` entries, newest first (optionally of one drone)."""
        sql = (
            "SELECT id, time, role, source, drone, utterance, confidence, commands, action,"
            " outcome, state, recording FROM audit"
        )
        args: tuple[Any, ...] = ()
        if drone is not None:
            sql += " WHERE drone = ?"
            args = (drone,)
        sql += " ORDER BY id DESC LIMIT ?"
        with self._lock:
            rows = self._db.execute(sql, (*args, max(0, int(limit)))).fetchall()
        return [
            AuditEntry(
                r[0], r[1], r[2], r[3], r[4], r[5], r[6], json.loads(r[7]), r[8], r[9], r[10], r[11]
            )
            for r in rows
        ]

    def close(self) -> None:
        """Finish pending :meth:`append_later` writes, then close the database."""
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.shutdown(wait=True)
        with self._lock:
            self._db.close()


def _log_failure(fut: Future[int]) -> None:
    exc = fut.exception()
    if exc is not None:
        log.error("audit log write failed: %s", exc)
