"""Processes a test starts: one running with its output in a log, stopped at the end; a
vehicle key made by ``uav-console vehicle-key``."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STOP_S = 20.0  # SIGTERM's grace (a vehicle lands and closes its bus session), then SIGKILL


@contextlib.contextmanager
def running(
    argv: list[str], log_path: Path, env: Mapping[str, str], cwd: Path = ROOT
) -> Iterator[subprocess.Popen[bytes]]:
    """``argv`` running in ``cwd`` with stdout and stderr in ``log_path``; terminated when the
    block ends (killed if it has not exited ``STOP_S`` later)."""
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(argv, cwd=cwd, env=dict(env), stdout=log, stderr=log)
    try:
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(STOP_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def vehicle_key(data: Path, name: str) -> str:
    """A new vehicle key for ``name`` in the data directory ``data`` (``vehicle-key --print``)."""
    out = subprocess.run(
        [sys.executable, "-m", "server", "vehicle-key", name, "--data-dir", str(data), "--print"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    return out.stdout.strip()
