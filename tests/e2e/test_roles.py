"""Roles as a third-party client meets them: an observer watches, only a pilot commands.

The observer speaks rosbridge v2 through the ``websockets`` library (it needs to read the
``status`` op, which roslibpy drops); the pilot is roslibpy. The drone stays on the ground:
``/cmd_vel`` on a landed drone still switches the vehicle into manual mode, which REST shows.
"""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

import roslibpy
import websockets

from tests.support.polling import wait_for

from .conftest import OBSERVER, Server

JOG = {"linear": {"x": 0.3, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}


async def _status_for(ws: Any, op_id: str, timeout: float = 5.0) -> dict[str, Any]:
    """Read frames until the ``status`` op answering ``op_id`` (other frames are skipped)."""
    deadline = asyncio.get_running_loop().time() + timeout
    while True:
        left = deadline - asyncio.get_running_loop().time()
        assert left > 0, f"no status for {op_id}"
        msg = json.loads(await asyncio.wait_for(ws.recv(), left))
        if msg.get("op") == "status" and msg.get("id") == op_id:
            return dict(msg)


async def test_observer_may_watch_but_not_jog(landed: Server) -> None:
    srv = landed
    before = await asyncio.to_thread(srv.truth)
    async with websockets.connect(srv.ws_url(OBSERVER)) as ws:
        # watching works: navdata arrives
        await ws.send(json.dumps({"op": "subscribe", "id": "s", "topic": "/ardrone/navdata"}))
        first = json.loads(await asyncio.wait_for(ws.recv(), 5.0))
        assert first["op"] == "publish" and first["topic"] == "/ardrone/navdata"
        assert "batteryPercent" in first["msg"]
        await ws.send(json.dumps({"op": "unsubscribe", "id": "s", "topic": "/ardrone/navdata"}))

        for i in range(10):
            await ws.send(
                json.dumps({"op": "publish", "id": f"p{i}", "topic": "/cmd_vel", "msg": JOG})
            )
        status = await _status_for(ws, "p0")
        assert status["level"] == "error"
        assert "observer" in status["msg"] and "/cmd_vel" in status["msg"]
        await ws.send(
            json.dumps({"op": "publish", "id": "t", "topic": "/ardrone/takeoff", "msg": {}})
        )
        assert "observer" in (await _status_for(ws, "t"))["msg"]
        # a read-only service is fine for an observer
        await ws.send(
            json.dumps(
                {
                    "op": "call_service",
                    "id": "c",
                    "service": "/console/interpret",
                    "args": {"text": "land"},
                }
            )
        )
        while True:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 5.0))
            if msg.get("op") == "service_response" and msg.get("id") == "c":
                break
        assert msg["result"] is True
        assert msg["values"]["commands"] == [{"action": "land"}]

    drone = await asyncio.to_thread(srv.drone)
    assert drone["mode"] == "idle", drone
    after = await asyncio.to_thread(srv.truth)
    assert not after["flying"] and after["z"] < 0.05
    assert abs(after["x"] - before["x"]) < 0.01 and abs(after["y"] - before["y"]) < 0.01


def test_pilot_jog_then_operator_watchdog(landed: Server) -> None:
    """The same /cmd_vel from a pilot takes effect; silence for 1 s hands back to hover."""
    srv = landed
    ros = roslibpy.Ros(srv.ws_url())
    ros.run(timeout=10)
    try:
        cmd_vel = roslibpy.Topic(ros, "/cmd_vel", "geometry_msgs/Twist")
        cmd_vel.publish(roslibpy.Message(JOG))
        manual = wait_for(srv.drone, lambda d: d["mode"] == "manual", 5.0, "manual mode")
        last = time.monotonic()
        assert manual["mode"] == "manual"
        wait_for(srv.drone, lambda d: d["mode"] == "idle", 4.0, "watchdog back to idle")
        # the watchdog waits for the heartbeat timeout (1 s) before it hovers
        assert time.monotonic() - last > 0.8
    finally:
        ros.close()
