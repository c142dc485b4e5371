"""The whole server recording a real (simulated) flight, judged by Foxglove's own libraries.

``python -m server serve`` runs in a subprocess with the AR.Drone simulator on a loopback address of
its own and the recorder on (its default), a short idle time so the session ends soon after landing.
The pilot takes off and lands by text over REST, as a user would. Meanwhile Foxglove's Rosbridge
connection (tests/node/foxglove_client.mjs: @foxglove/roslibjs, @foxglove/rosmsg,
@foxglove/rosmsg-serialization) lists the topics with their definitions, sees ROS 1 by ``/rosout``
and decodes every topic from cbor-raw; afterwards Foxglove's MCAP reader (@mcap/core) decodes every
message of the downloaded recording. The recording is then replayed with ``uav-console replay`` and
watched through REST and rosbridge.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cbor2
import httpx
import pytest

from server.cli import main as cli_main
from server.recorder.mcapfile import read_recording
from server.ros1 import codec_for
from tests.rosbridge.wsclient import RawClient
from tests.support.loopback import free_port, fresh_address
from tests.support.polling import until, wait_for

ROOT = Path(__file__).resolve().parents[2]
NODE_DIR = ROOT / "tests" / "node"
PILOT, OBSERVER = "fox-pilot", "fox-observer"
SIM_ADDR = fresh_address()


def node_exe() -> str:
    exe = shutil.which("node")
    if exe is None:
        pytest.skip("node is not installed (apt-get install nodejs npm)")
    if not (NODE_DIR / "node_modules" / "@mcap" / "core").is_dir():
        subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=NODE_DIR, check=True)
    return exe


def node(*args: str, timeout: float = 60) -> dict[str, Any]:
    out = subprocess.run(
        [node_exe(), "foxglove_client.mjs", *args],
        cwd=NODE_DIR,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    result: dict[str, Any] = json.loads(out.stdout or "{}")
    assert out.returncode == 0 and "fatal" not in result, (result, out.stderr[-2000:])
    return result


@contextlib.contextmanager
def serve(cmd: list[str], data: Path, port: int, ready: str, **env: str) -> Iterator[httpx.Client]:
    log_path = data / f"server-{port}.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "server", *cmd, "--port", str(port)],
            cwd=ROOT,
            env=dict(os.environ, **env),
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    http = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10.0)
    try:

        def is_ready() -> bool:
            if proc.poll() is not None:
                raise RuntimeError(f"server exited:\n{log_path.read_text()[-3000:]}")
            return http.get(ready, headers={"Authorization": f"Bearer {env['TOKEN']}"}).is_success

        try:
            until(is_ready, 40.0, "the server ready", ignore=(httpx.TransportError,))
        except AssertionError:
            raise RuntimeError(f"server did not start:\n{log_path.read_text()[-3000:]}") from None
        yield http
    finally:
        http.close()
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """Fly once (take off, hover, land) with Foxglove watching live; the recording's facts."""
    node_exe()
    data = tmp_path_factory.mktemp("fox-data")
    port = free_port()
    pilot = {"Authorization": f"Bearer {PILOT}"}
    cmd = ["serve", "--token", PILOT, "--observer-token", OBSERVER, "--data-dir", str(data)]
    env = {
        "TOKEN": PILOT,
        "UAVC_SIM_BASE_ADDR": SIM_ADDR,
        "UAVC_RECORDER_IDLE_S": "2",
        "UAVC_RECORDER_CHUNK_S": "0.5",
        # recording, not isolation: flight stacks inline unless UAVC_VEHICLES says otherwise
        "UAVC_VEHICLES": os.environ.get("UAVC_VEHICLES", "inline"),
    }
    with serve(cmd, data, port, "/api/v1/health", **env) as http:
        http.headers.update(pilot)
        truth = lambda: http.get("/api/v1/sim/uav1/truth").json()  # noqa: E731
        said = http.post("/api/v1/command", json={"text": "take off"}).json()
        assert said["accepted"], said
        wait_for(truth, lambda t: t["flying"] and t["z"] > 0.5, 20, "airborne")
        during = http.get("/api/v1/flights").json()["flights"]
        url = f"ws://127.0.0.1:{port}/rosbridge?token={PILOT}"
        with subprocess.Popen(
            [node_exe(), "foxglove_client.mjs", "live", url, "4"],
            cwd=NODE_DIR,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        ) as watcher:
            assert watcher.stderr is not None
            first = watcher.stderr.readline()  # "subscribed": every topic is being watched
            assert first.strip() == "subscribed", first
            time.sleep(0.5)
            http.post("/api/v1/command", json={"text": "how much battery is left"})
            out, err = watcher.communicate(timeout=60)
        live = json.loads(out or "{}")
        assert watcher.returncode == 0 and "fatal" not in live, (live, err[-2000:])
        busy = http.get(f"/api/v1/flights/{during[0]['id']}")
        http.post("/api/v1/command", json={"text": "land"})
        wait_for(truth, lambda t: not t["flying"] and t["z"] < 0.05, 20, "landed")
        rows = wait_for(
            lambda: http.get("/api/v1/flights").json()["flights"],
            lambda f: len(f) == 1 and f[0]["ended"] is not None,
            20,
            "the session to end after landing",
        )
        download = http.get(f"/api/v1/flights/{rows[0]['id']}")
        path = data / "downloaded.mcap"
        path.write_bytes(download.content)
        audit = sqlite3.connect(data / "audit.db")
        recordings = list(
            audit.execute("SELECT utterance, recording, action FROM audit ORDER BY id")
        )
        audit.close()
        observer = {"Authorization": f"Bearer {OBSERVER}"}
        deletes = {
            "observer": http.delete(f"/api/v1/flights/{rows[0]['id']}", headers=observer),
            "unknown": http.delete("/api/v1/flights/20000101T000000Z"),
            "unknown_get": http.get("/api/v1/flights/20000101T000000Z"),
            "pilot": http.delete(f"/api/v1/flights/{rows[0]['id']}"),
        }
        after = http.get("/api/v1/flights").json()["flights"]
        yield {
            "during": during,
            "busy": busy,
            "rows": rows,
            "download": download,
            "path": path,
            "live": live,
            "recordings": recordings,
            "deletes": deletes,
            "after": after,
            "data": data,
        }


def test_the_flight_is_one_recording_listed_and_downloadable(flight: dict[str, Any]) -> None:
    (during,) = flight["during"]
    assert during["ended"] is None and during["drones"] == ["uav1"]
    assert flight["busy"].status_code == 409  # still being written
    (row,) = flight["rows"]
    assert row["id"] == during["id"] and row["drones"] == ["uav1"]
    assert row["started"] < row["ended"] and row["messages"] > 100
    d = flight["download"]
    assert d.status_code == 200 and d.headers["content-type"] == "application/octet-stream"
    assert f'filename="uav-console-{row["id"]}.mcap"' in d.headers["content-disposition"]
    assert len(d.content) == row["bytes"]
    # the take-off, the battery question and the landing (and any ANS action in between)
    # are audited with the recording's id: each utterance once as its intent, before it is
    # acted on, and once with its outcome (issue 14)
    rows = flight["recordings"]
    assert {r for _u, r, _a in rows} == {row["id"]}
    flown = ("take off", "how much battery is left", "land")
    intents = [u for u, _r, a in rows if u in flown and a == "intent:utterance"]
    outcomes = [u for u, _r, a in rows if u in flown and a != "intent:utterance"]
    assert intents == outcomes == list(flown), rows


def test_delete_is_pilot_only(flight: dict[str, Any]) -> None:
    deletes = flight["deletes"]
    assert deletes["observer"].status_code == 403
    assert "observer" in deletes["observer"].json()["detail"]
    assert deletes["unknown"].status_code == 404 and deletes["unknown_get"].status_code == 404
    assert deletes["pilot"].status_code == 200
    assert flight["after"] == []


def test_foxglove_live_decodes_every_topic_from_cbor_raw(flight: dict[str, Any]) -> None:
    live = flight["live"]
    assert live["rosVersion"] == 1 and live["rosoutType"] == "rosgraph_msgs/Log"
    topics = live["topics"]
    unparsed = {t: e.get("error") for t, e in topics.items() if not e.get("parsed")}
    assert unparsed == {}
    errors = {t: e["error"] for t, e in topics.items() if "error" in e}
    assert errors == {}
    for name in ("/ardrone/navdata", "/ardrone/image_raw/compressed", "/uav/pose", "/rosout"):
        assert topics[name]["count"] > 0, name
    image = topics["/ardrone/image_raw/compressed"]["sample"]
    assert image["format"] == "jpeg" and image["data"]["head"][:2] == [0xFF, 0xD8]
    assert topics["/ardrone/navdata"]["sample"]["state"] in (
        3,
        4,
        6,
        7,
    )  # taking off, flying, hovering
    assert topics["/ardrone/navdata"]["receiveTime"]["secs"] > 1_600_000_000


def test_foxglove_reads_every_message_of_the_recording(flight: dict[str, Any]) -> None:
    fox = node("mcap", str(flight["path"]))
    assert fox["errors"] == []
    assert fox["messages"] == fox["statistics"] == fox["streamed"] == flight["rows"][0]["messages"]
    assert fox["streamDone"]
    topics = fox["topics"]
    for name in (
        "/ardrone/navdata",
        "/ardrone/image_raw/compressed",
        "/uav/pose",
        "/uav/task",
        "/console/reply",
        "/console/state",
        "/rosout",
    ):
        assert topics[name]["count"] > 0, name
        assert topics[name]["schemaEncoding"] == "ros1msg", name
    assert topics["/ardrone/image_raw/compressed"]["type"] == "sensor_msgs/CompressedImage"
    assert all(t["count"] == 0 or "sample" in t for t in topics.values())
    ours = read_recording(flight["path"])
    # REST commands reach the dialog directly; each reply names the utterance it answers
    said = [m["utterance"] for c, _t, m in ours.decoded() if c.topic == "/console/reply"]
    assert [s for s in said if s] == ["take off", "how much battery is left", "land"]
    states = {m["state"] for c, _t, m in ours.decoded() if c.topic == "/ardrone/navdata"}
    assert {2, 3} <= states or {2, 4} <= states  # landed and in the air


async def _replay_checks(port: int) -> dict[str, Any]:
    client = await RawClient.open(f"ws://127.0.0.1:{port}/rosbridge?token={OBSERVER}")
    try:
        await client.send(
            {"op": "subscribe", "topic": "/ardrone/navdata", "compression": "cbor-raw", "id": "n"}
        )
        frame = await client.expect(lambda m: isinstance(m, bytes), 10, "a cbor-raw navdata")
        body = cbor2.loads(frame)
        nav = codec_for("ardrone_autonomy/Navdata").decode(body["msg"]["bytes"])
        await client.send({"op": "subscribe", "topic": "/console/utterance", "id": "u"})
        return {"nav": nav, "body": body}
    finally:
        await client.ws.close()


def test_replay_serves_the_recording_read_only_with_a_timeline(
    flight: dict[str, Any], tmp_path: Path
) -> None:
    port = free_port()
    cmd = ["replay", str(flight["path"]), "--speed", "4", "--token", OBSERVER]
    with serve(cmd, tmp_path, port, "/api/v1/replay", TOKEN=OBSERVER) as http:
        http.headers["Authorization"] = f"Bearer {OBSERVER}"
        status = http.get("/api/v1/replay").json()
        assert status["playing"] and status["speed"] == 4
        assert status["drones"] == ["uav1"] and status["duration_s"] > 3
        (drone,) = http.get("/api/v1/drones").json()
        assert drone["name"] == "uav1" and drone["replay"] is True
        with http.stream("GET", "/api/v1/drones/uav1/video.mjpg") as video:
            head = b""
            for chunk in video.iter_bytes():
                head += chunk
                if b"\xff\xd8" in head:
                    break
        assert b"Content-Type: image/jpeg" in head  # the recorded camera, as MJPEG
        got = asyncio.run(_replay_checks(port))
        assert got["body"]["op"] == "publish" and got["nav"]["batteryPercent"] > 0
        paused = http.post("/api/v1/replay", json={"action": "pause"}).json()
        assert not paused["playing"]
        seek = http.post("/api/v1/replay", json={"action": "seek", "position_s": 0.5}).json()
        assert seek["position_s"] == pytest.approx(0.5) and not seek["playing"]
        assert http.post("/api/v1/replay", json={"action": "warp"}).status_code == 422
        assert http.post("/api/v1/drones/uav1/takeoff").status_code == 403  # observer page
        topics = http.get("/api/v1/replay").json()
        assert topics["messages"] == flight["rows"][0]["messages"]


def test_replay_refuses_bad_files_naming_the_offset(
    flight: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = flight["path"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x00" * 64)

    def replay(*args: str) -> subprocess.CompletedProcess[str]:
        """``uav-console replay ARGS`` in this process (its exit code and stderr): each of
        these fails before serving anything."""
        try:
            code = cli_main(["replay", *args])
        except SystemExit as exc:  # argparse's refusals
            code = int(exc.code or 0)
        err = capsys.readouterr().err
        return subprocess.CompletedProcess(["replay", *args], code, "", err)

    r = replay(str(cut))
    assert r.returncode == 2
    assert "truncated" in r.stderr and "byte offset" in r.stderr and "--recover" in r.stderr
    r = replay(str(junk))
    assert r.returncode == 2 and "not an MCAP file" in r.stderr and "offset 0" in r.stderr
    r = replay(str(tmp_path / "missing.mcap"))
    assert r.returncode == 2 and "cannot read" in r.stderr
    r = replay(str(flight["path"]), "--speed", "0")
    assert r.returncode == 2 and "--speed" in r.stderr
