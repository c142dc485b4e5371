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
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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


class AuditLog:
    """Append-only SQLite audit log; safe to call from several threads."""

    def __init__(self, path: Path | str, clock: Callable[[], float] = time.time) -> None:
        """Open (creating if needed) the log at ``path`` (``":memory:"`` for tests).

        Raises:
            AuditError: the file cannot be opened or is not a usable database.
        """
        self.path = str(path)
        self._clock = clock
        self._lock = threading.Lock()
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
            role,
            source,
            drone,
            utterance,
            confidence,
            json.dumps(commands),
            action,
            outcome,
            state,
        )
        with self._lock:
            try:
                cur = self._db.execute(
                    "INSERT INTO audit (time, role, source, drone, utterance, confidence,"
                    " commands, action, outcome, state) VALUES (?,?,?,?,?,?,?,?,?,?)",
                    row,
                )
            except sqlite3.Error as exc:
                raise AuditError(f"cannot write audit log {self.path}: {exc}") from exc
            return int(cur.lastrowid or 0)

    def recent(self, limit: int = 50, drone: str | None = None) -> list[AuditEntry]:
        """The newest ``limit`` entries, newest first (optionally of one drone)."""
        sql = "SELECT * FROM audit"
        args: tuple[Any, ...] = ()
        if drone is not None:
            sql += " WHERE drone = ?"
            args = (drone,)
        sql += " ORDER BY id DESC LIMIT ?"
        with self._lock:
            rows = self._db.execute(sql, (*args, max(0, int(limit)))).fetchall()
        return [
            AuditEntry(
                r[0], r[1], r[2], r[3], r[4], r[5], r[6], json.loads(r[7]), r[8], r[9], r[10]
            )
            for r in rows
        ]

    def close(self) -> None:
        with self._lock:
            self._db.close()
