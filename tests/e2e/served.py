"""A real ``python -m server serve`` in a subprocess, for tests that need their own (another
world, a second console, the recorder): started, waited for, and always stopped."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from tests.support.polling import until, wait_for

ROOT = Path(__file__).resolve().parents[2]


@dataclass
class Served:
    """A running ``serve`` and a REST client holding its pilot token."""

    port: int
    token: str
    proc: subprocess.Popen[bytes]
    http: httpx.Client
    log_path: Path

    @property
    def ws(self) -> str:
        return f"ws://127.0.0.1:{self.port}/rosbridge?token={self.token}"

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def truth(self, drone: str = "uav1") -> dict[str, Any]:
        r = self.http.get(f"/api/v1/sim/{drone}/truth")
        r.raise_for_status()
        return dict(r.json())

    def wait_truth(
        self, pred: Callable[[dict[str, Any]], bool], timeout: float, what: str, drone: str = "uav1"
    ) -> dict[str, Any]:
        return wait_for(lambda: self.truth(drone), pred, timeout, what)

    def say(self, text: str, **extra: Any) -> dict[str, Any]:
        """``POST /api/v1/command`` (the pilot's lease is taken by the first command)."""
        r = self.http.post("/api/v1/command", json={"text": text, **extra})
        r.raise_for_status()
        return dict(r.json())


@contextlib.contextmanager
def serve(
    args: list[str],
    data: Path,
    *,
    token: str,
    env: dict[str, str] | None = None,
    drones: tuple[str, ...] = ("uav1",),
    timeout_s: float = 60.0,
) -> Iterator[Served]:
    """``serve --port P --token T --data-dir DATA *args`` until its drones are all up."""
    from tests.support.loopback import bus_endpoint, free_port

    port = free_port()
    log_path = data / f"serve-{port}.log"
    cmd = [sys.executable, "-m", "server", "serve", "--port", str(port), "--token", token]
    cmd += ["--data-dir", str(data), *args]
    full_env = {**os.environ, "UAVC_BUS_LISTEN": bus_endpoint(), **(env or {})}
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=full_env, stdout=log, stderr=subprocess.STDOUT)
    http = httpx.Client(
        base_url=f"http://127.0.0.1:{port}",
        headers={"Authorization": f"Bearer {token}"},
        timeout=15.0,
    )
    srv = Served(port, token, proc, http, log_path)
    try:

        def healthy() -> bool:
            if proc.poll() is not None:
                raise RuntimeError(f"serve exited with {proc.returncode}:\n{srv.log()[-4000:]}")
            up = http.get("/api/v1/health").json().get("drones", {})
            return all(up.get(d) for d in drones)

        try:
            until(healthy, timeout_s, "serve healthy", ignore=(httpx.TransportError, ValueError))
        except AssertionError:
            raise RuntimeError(f"serve did not become healthy:\n{srv.log()[-4000:]}") from None
        yield srv
    finally:
        http.close()
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
