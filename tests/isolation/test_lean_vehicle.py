"""The vehicle process is lean (issue 27): a whole vehicle started in a fresh interpreter
loads no web stack (FastAPI), no ONNX runtime, no speech, captioner or recorder, no NLU and no
dialog (the console's dialog drives the vehicle's task executor with typed commands)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.support.loopback import fresh_address

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def probe(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    data = tmp_path_factory.mktemp("lean")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [
            sys.executable,
            str(ROOT / "tests/isolation/lean_probe.py"),
            fresh_address(),
            str(data),
        ],
        capture_output=True,
        text=True,
        timeout=180,
        env=env,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


@pytest.mark.timeout(240)
@pytest.mark.parametrize(
    "part", ["fastapi", "onnxruntime", "speech", "captioner", "recorder", "nlu", "dialog"]
)
def test_the_vehicle_process_loads_none_of_the_web_stack(probe: dict[str, Any], part: str) -> None:
    assert part not in probe["loaded"], probe["loaded"]
