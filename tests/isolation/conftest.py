"""A real ``uav-console serve --vehicles process`` on a loopback address of its own, flying a
simulated AR.Drone that the test process runs itself (``drone.sim.probe.SimThread``), so the
test sees the drone's wire and its ground truth without asking the server under test."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
from websockets.sync.client import connect as ws_connect

from server.vehicles.door_protocol import Ack, Auth, Hello, Stop, encode, parse_door
from tests.support.loopback import bus_endpoint, free_port, fresh_address
from tests.support.polling import until

ROOT = Path(__file__).resolve().parents[2]
PILOT = "isolation-pilot-token"
HOST = fresh_address()


def wait_for(fn: Callable[[], Any], what: str, timeout: float = 20.0, period: float = 0.1) -> Any:
    """``until`` for a ``serve`` process: an HTTP error or a body without the field yet (the
    process still starting) means "not yet"."""
    return until(
        fn, timeout, what, period=period, ignore=(httpx.HTTPError, KeyError, ValueError, TypeError)
    )


@dataclass
class Served:
    """A ``serve`` process and a pilot REST client to it."""

    port: int
    proc: subprocess.Popen[bytes]
    http: httpx.Client
    log_path: Path
    host: str = HOST

    @property
    def ws(self) -> str:
        return f"ws://{self.host}:{self.port}/rosbridge?token={PILOT}"

    def drone(self, name: str = "uav1") -> dict[str, Any]:
        r = self.http.get(f"/api/v1/drones/{name}")
        r.raise_for_status()
        return dict(r.json())

    def vehicle(self, name: str = "uav1") -> dict[str, Any]:
        return dict(self.drone(name)["vehicle"])

    def wait_vehicle(self, name: str = "uav1", timeout: float = 30.0) -> dict[str, Any]:
        """Wait until the vehicle process is connected and its drone link is up."""

        def ready() -> dict[str, Any] | None:
            d = self.drone(name)
            ok = d["vehicle"]["connected"] and d["link_ok"] and d["vehicle"]["door_url"]
            return d["vehicle"] if ok else None

        return dict(wait_for(ready, f"{name}'s vehicle process", timeout))

    def command(self, text: str) -> dict[str, Any]:
        r = self.http.post("/api/v1/command", json={"text": text})
        r.raise_for_status()
        return dict(r.json())

    def command_again_if_late(self, text: str, tries: int = 3) -> dict[str, Any]:
        """``command(text)``, said again while the vehicle refuses it as late ("Not flown: …
        reached the drone 2.5 s after you gave it"): a machine too busy to carry a sentence
        within the 2 s deadline, where an operator says it again. For a test's set-up only."""
        out = self.command(text)
        for _ in range(tries - 1):
            if out["accepted"] or "Not flown" not in str(out.get("reply", "")):
                break
            out = self.command(text)
        return out

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-4000:]

    def pause(self) -> None:
        os.kill(self.proc.pid, signal.SIGSTOP)

    def resume(self) -> None:
        os.kill(self.proc.pid, signal.SIGCONT)

    def assert_rejoined_after_long_loss(self, pid: int) -> None:
        """The web process is back: vehicle ``pid`` reconnected (not restarted) after hovering
        and then landing while it heard nothing."""
        again = self.wait_vehicle()
        assert again["pid"] == pid, "the vehicle should reconnect, not be restarted"
        assert self.drone()["central_loss"]["actions"][-2:] == ["hover", "land"]


@contextlib.contextmanager
def serve(
    tmp: Path,
    drone: str,
    *,
    extra: tuple[str, ...] = (),
    env: dict[str, str] | None = None,
    port: int | None = None,
    host: str = HOST,
    start_s: float = 30,
) -> Iterator[Served]:
    port = port or free_port(host)
    log_path = tmp / f"serve-{port}.log"
    full_env = {**os.environ, "UAVC_DATA_DIR": str(tmp / "data"), "UAVC_BUS_LISTEN": bus_endpoint()}
    full_env["UAVC_ASR_PRELOAD"] = "false"  # no test here speaks: no model loaded beside the start
    full_env.update(env or {})
    argv = [sys.executable, "-m", "server", "serve", "--host", host, "--port", str(port)]
    argv += ["--drone", drone, "--token", PILOT, *extra]
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(argv, cwd=ROOT, env=full_env, stdout=log, stderr=log)
    http = httpx.Client(
        base_url=f"http://{host}:{port}", headers={"Authorization": f"Bearer {PILOT}"}, timeout=10
    )
    served = Served(port, proc, http, log_path, host)
    try:
        wait_for(lambda: http.get("/api/v1/health").status_code == 200, "serve to start", start_s)
        yield served
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGCONT)
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        http.close()


def door_stop(url: str, token: str, action: str, stop_id: str, issued: float | None = None) -> Ack:
    """Open the vehicle's safety door (``websockets``), send one stop, return its ack."""
    with ws_connect(url, open_timeout=10) as ws:
        ws.send(encode(Auth(token)))
        assert isinstance(parse_door(ws.recv(timeout=10)), Hello)
        ws.send(encode(Stop(action, stop_id, issued)))
        while True:
            msg = parse_door(ws.recv(timeout=10))
            if isinstance(msg, Ack):
                return msg


def reply_texts(frames: list[str]) -> list[str]:
    out = []
    for f in frames:
        obj = json.loads(f)
        if obj.get("op") == "publish" and obj.get("topic") == "/console/reply":
            out.append(str(obj["msg"]["text"]))
    return out
