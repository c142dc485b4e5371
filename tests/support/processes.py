"""Processes a test starts: one running with its output in a log, stopped at the end; a
vehicle key made by ``uav-console vehicle-key``; a vehicle process joining a bus with it."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

from tests.support.loopback import fresh_address

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


@contextlib.contextmanager
def bus_vehicle(
    tmp: Path, endpoint: str, name: str, key: str, extra_env: Mapping[str, str] | None = None
) -> Iterator[tuple[subprocess.Popen[bytes], Path]]:
    """``uav-console vehicle --bus-connect ENDPOINT --name NAME`` with ``key``, as on a drone's
    own computer (a data directory of its own, no console token, its own simulator address);
    the process and its log."""
    log_path = tmp / f"{name}.log"
    env = {
        **os.environ,
        "UAVC_VEHICLE_KEY": key,
        "UAVC_DATA_DIR": str(tmp / f"{name}-computer"),
        "UAVC_SIM_BASE_ADDR": fresh_address(),
        **(extra_env or {}),
    }
    env.pop("UAVC_TOKEN", None)
    argv = [sys.executable, "-m", "server", "vehicle", "--bus-connect", endpoint, "--name", name]
    with running(argv, log_path, env) as proc:
        yield proc, log_path
