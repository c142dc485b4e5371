"""Checks over the tracked files. Lint and types (ruff, mypy --strict) are `make lint`, which
`.ci/run` runs beside the tests."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_no_merge_conflict_markers() -> None:
    """A conflict marker left by a merge breaks the file around it silently: in CSS the rule
    after a stray ``=======`` is dropped (the replay bar lost its layout that way)."""
    files = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b"\0")
    found = []
    for name in filter(None, files):
        path = ROOT / name.decode()
        if not path.is_file() or path.suffix in {".png", ".jpg", ".onnx", ".mcap", ".wav"}:
            continue
        for n, line in enumerate(path.read_bytes().splitlines(), 1):
            if line.startswith((b"<<<<<<< ", b">>>>>>> ")) or line == b"=======":
                found.append(f"{name.decode()}:{n}")
    assert not found, f"merge conflict markers: {found}"
