"""roslibjs (npm ``roslib``, unchanged, on Node) against our server; see tests/node/.

The Node script runs every scenario and prints what it saw; this test checks each one.
``node`` must be installed; the npm packages come from ``tests/node/package-lock.json``
(``npm ci --prefix tests/node``; the fixture runs it when ``node_modules`` is missing).
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from .server_fixture import RunningServer

NODE_DIR = Path(__file__).resolve().parent.parent / "node"
pytestmark = pytest.mark.node


@pytest.fixture(scope="module")
def node() -> str:
    exe = shutil.which("node")
    if exe is None:
        pytest.skip("node is not installed (apt-get install nodejs npm)")
    if not (NODE_DIR / "node_modules" / "roslib").exists():
        npm = shutil.which("npm")
        assert npm, "npm is needed to install roslib (apt-get install npm)"
        subprocess.run(
            [npm, "ci", "--no-audit", "--no-fund"], cwd=NODE_DIR, check=True, timeout=300
        )
    return exe


def test_roslibjs_scenarios(srv: RunningServer, node: str) -> None:
    async def echo(args: dict[str, Any]) -> dict[str, Any]:
        return {"text": args.get("text", "") + "!"}

    srv.call(srv.graph.advertise_service, "/py/echo", "example/Echo", echo)
    srv.call(srv.graph.advertise, "/py/ticker", "std_msgs/Int32")

    async def ticker() -> None:
        n = 0
        while True:
            n += 1
            srv.graph.publish("/py/ticker", {"data": n})
            await asyncio.sleep(0.02)  # a 50 Hz topic: the rate is the test's input

    tick = asyncio.run_coroutine_threadsafe(ticker(), srv.loop)
    try:
        proc = subprocess.run(
            [node, "roslib_client.mjs", srv.url()],
            cwd=NODE_DIR,
            capture_output=True,
            text=True,
            timeout=90,
        )
    finally:
        tick.cancel()
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    errors = {k: v for k, v in r.items() if isinstance(v, dict) and "error" in v}
    assert not errors, errors

    assert r["pubsub"]["data"].startswith("hello ")
    assert isinstance(r["from_graph"]["data"], int)
    assert r["latched"] == {"data": "kept"}
    assert r["client_service"] == {"sum": 42}
    assert r["graph_service"] == {"text": "ping!"}
    assert "does not exist" in r["service_failure"]["failed"]
    assert r["params"]["got"] == {"k": [1, 2, 3]}
    assert "/js_param" not in r["params"]["names"]
    assert "/js/chatter" in r["topics"]["topics"]
    vec = {"x": "float64", "y": "float64", "z": "float64"}  # decodeTypeDefs: like rosmsg show
    assert r["message_details"] == {"linear": vec, "angular": vec}
    # throttle_rate 1000 ms, queue_length 0: a burst of 10 within the window gives only the first
    assert r["throttle"] == [1]
    # throttle_rate 300 ms, queue_length 2: the first at once, then the newest two (oldest dropped)
    assert r["queue"] == [1, 9, 10]
    assert r["fragments"] == {"data": "x" * 3000 + "END"}
    assert r["png"] == {"data": "through a png"}
    cbor = r["cbor"]
    assert cbor["dataIsBytes"] and cbor["data"] == [255, 216, 1, 2, 3, 255, 217]
    assert cbor["format"] == "jpeg" and cbor["stampSec"] == "number"
    assert cbor["battery"] == 87.5
    assert cbor["tagsXcType"] == "Uint32Array" and cbor["tagsXc"] == [10, 20, 300000]
    assert cbor["tagsDistanceType"] == "Float32Array" and cbor["tagsDistance"] == [1.5, 2.25]
    status = r["status"]
    assert status["level"] == "error" and status["id"] == "bad-1"
    assert "msg.data must be a string" in status["msg"]
