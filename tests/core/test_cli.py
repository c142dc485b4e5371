"""The ``uav-console`` command as a person runs it: a real process, real sockets."""

from __future__ import annotations

import json
import os
import signal
import socket
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.support.loopback import bound_socket, free_port

ROOT = Path(__file__).resolve().parents[2]


def uav_console(*args: str, **kw: object) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "server", *args],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,  # type: ignore[arg-type]
    )


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], int, Path]]:
    port = free_port()
    proc = uav_console("serve", "--port", str(port), "--drone", "none", "--data-dir", str(tmp_path))
    try:
        yield proc, port, tmp_path
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.close()
        proc.stderr.close()


def test_serve_prints_one_clickable_pilot_url_and_stores_tokens_0600(
    served: tuple[subprocess.Popen[str], int, Path],
) -> None:
    proc, port, data_dir = served
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    assert line.startswith(f"http://127.0.0.1:{port}/?token=")
    # The URL answers the moment it is printed: with the server frozen right after printing it,
    # the kernel still accepts the connection, so the socket was listening before the print.
    proc.send_signal(signal.SIGSTOP)
    try:
        socket.create_connection(("127.0.0.1", port), timeout=10).close()
    finally:
        proc.send_signal(signal.SIGCONT)
    token = line.split("token=", 1)[1]
    token_files = [p for p in data_dir.iterdir() if p.is_file()]
    assert token_files, "no token file written"
    for p in token_files:
        assert stat.S_IMODE(p.stat().st_mode) == 0o600
    with httpx.Client(base_url=f"http://127.0.0.1:{port}") as client:
        assert client.get("/api/v1/health").json()["status"] in {"ok", "degraded"}
        assert client.get("/version").json()["protocol"]["major"] == 2
        assert client.get("/api/v1/world").status_code == 401
        world = client.get("/api/v1/world", headers={"Authorization": f"Bearer {token}"})
        assert world.status_code == 200
        page = client.get(f"/?token={token}")
        assert page.status_code == 200 and "<html" in page.text.lower()
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=20) == 0


def test_serve_keeps_the_same_tokens_across_restarts(tmp_path: Path) -> None:
    lines = []
    for _ in range(2):
        port = free_port()
        proc = uav_console(
            "serve", "--port", str(port), "--drone", "none", "--data-dir", str(tmp_path)
        )
        assert proc.stdout is not None
        lines.append(proc.stdout.readline().split("token=", 1)[1].strip())
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=20)
    assert lines[0] == lines[1]


def test_serve_runs_flight_stacks_in_their_own_processes_unless_told_inline() -> None:
    """``serve``'s default is the model's one default (``process``); the environment beats it
    and the flag beats both."""
    from server.cli import _parser, settings_from

    def vehicles(flags: list[str], env: dict[str, str]) -> str:
        return settings_from(_parser().parse_args(["serve", *flags]), env).vehicles

    assert vehicles([], {}) == "process"
    assert vehicles([], {"UAVC_VEHICLES": "inline"}) == "inline"
    assert vehicles(["--vehicles", "inline"], {"UAVC_VEHICLES": "process"}) == "inline"
    assert vehicles(["--vehicles", "process"], {"UAVC_VEHICLES": "inline"}) == "process"


def test_a_port_already_taken_is_a_clear_error(tmp_path: Path) -> None:
    with bound_socket() as taken:
        taken.listen()
        port = taken.getsockname()[1]
        out = subprocess.run(
            [sys.executable, "-m", "server", "serve", "--port", str(port), "--drone", "none",
             "--data-dir", str(tmp_path)],
            cwd=ROOT, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
    assert out.returncode == 2, out.stderr
    assert f"cannot listen on 127.0.0.1:{port}" in out.stderr and "Traceback" not in out.stderr
    assert "token=" not in out.stdout  # nothing announced: no URL that does not answer


def test_bad_environment_setting_is_a_clear_error(tmp_path: Path) -> None:
    env = {**os.environ, "UAVC_PORT": "eighty"}
    out = subprocess.run(
        [sys.executable, "-m", "server", "serve", "--data-dir", str(tmp_path)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert "UAVC_PORT" in out.stderr


def test_interpret_one_text_and_stdin_lines() -> None:
    one = subprocess.run(
        [sys.executable, "-m", "server", "interpret", "take off and go to marker 3"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert one.returncode == 0, one.stderr
    body = json.loads(one.stdout)
    assert body == {
        "text": "take off and go to marker 3",
        "commands": [{"action": "takeoff"}, {"action": "goto", "marker": 3}],
    }
    lines = subprocess.run(
        [sys.executable, "-m", "server", "interpret"],
        cwd=ROOT,
        input="land\nflibber the wobble\n",
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert lines.returncode == 0, lines.stderr
    out = [json.loads(x) for x in lines.stdout.splitlines()]
    assert out == [
        {"text": "land", "commands": [{"action": "land"}]},
        {"text": "flibber the wobble", "commands": []},
    ]
