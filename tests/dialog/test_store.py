"""The SQLite audit log: entries, queries, and durability across a SIGKILL of the writer."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from server.store import AuditError, AuditLog

ROOT = Path(__file__).resolve().parents[2]


def test_append_and_recent(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "audit.db", clock=lambda: 1000.0)
    log.append(
        utterance="take off",
        commands=[{"action": "takeoff"}],
        action="executed",
        outcome="Taking off.",
        role="pilot",
        source="speech",
        confidence=0.9,
    )
    log.append(
        utterance="land",
        commands=[{"action": "land"}],
        action="executed",
        outcome="Landing.",
        drone="uav2",
    )
    recent = log.recent(10)
    assert [e.utterance for e in recent] == ["land", "take off"]
    assert recent[1].commands == [{"action": "takeoff"}] and recent[1].time == 1000.0
    assert recent[1].confidence == 0.9 and recent[1].role == "pilot"
    assert [e.utterance for e in log.recent(10, drone="uav2")] == ["land"]
    assert log.recent(0) == []
    mode = log._db.execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"
    log.close()


def test_unusable_path_gives_audit_error(tmp_path: Path) -> None:
    bad = tmp_path / "not_a_db"
    bad.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(AuditError, match="cannot open audit log"):
        AuditLog(bad)


WRITER = """
import os, signal, sys
from server.store import AuditLog
log = AuditLog(sys.argv[1])
for i in range(20):
    log.append(utterance=f"u{i}", commands=[], action="executed", outcome="ok")
print("written", flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_entries_survive_sigkill(tmp_path: Path) -> None:
    db = tmp_path / "audit.db"
    proc = subprocess.run(
        [sys.executable, "-c", WRITER, str(db)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert "written" in proc.stdout
    log = AuditLog(db)
    assert [e.utterance for e in log.recent(100)] == [f"u{i}" for i in reversed(range(20))]
    log.close()


def test_append_later_writes_in_order_off_the_callers_thread(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import threading

    from server.store import AuditLog

    log = AuditLog(tmp_path / "audit.db")
    caller = threading.get_ident()
    seen_threads: list[int] = []
    real = log.append

    def spy(**kw):  # type: ignore[no-untyped-def]
        seen_threads.append(threading.get_ident())
        return real(**kw)

    log.append = spy  # type: ignore[method-assign]
    futs = [
        log.append_later(utterance="", commands=[{"action": a}], action="executed", outcome=a)
        for a in ("emergency", "reset", "takeoff")
    ]
    assert [f.result(timeout=5) for f in futs] == [1, 2, 3]
    assert caller not in seen_threads
    log.close()  # waits for pending writes
    again = AuditLog(tmp_path / "audit.db")
    assert [e.outcome for e in again.recent(3)] == ["takeoff", "reset", "emergency"]
    again.close()
