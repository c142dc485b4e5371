"""Command deadlines at the rosbridge door: ``issued`` on a publish, judged where the console
hands the command over, carried on to subscribers (a vehicle judges it again).

The protocol and the graph without sockets; the rest against a real uvicorn server on
loopback with real WebSocket clients (``tests.rosbridge.server_fixture``).
"""

from __future__ import annotations

import asyncio
import json
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from server.graph import Graph
from server.http.audit_trail import AuditTrail
from server.rosbridge import ops
from server.rosbridge.protocol import BridgeProtocol
from server.store import AuditLog
from tests.rosbridge.server_fixture import RunningServer, running_server
from tests.rosbridge.wsclient import RawClient
from tests.support.polling import until, until_async

EMPTY = "std_msgs/Empty"
TWIST = "geometry_msgs/Twist"
JOG = {"linear": {"x": 0.3, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}
STILL = {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}}


# -- protocol and graph (no sockets) ------------------------------------------------------------
def test_publish_carries_issued_and_unknown_fields_stay_tolerated() -> None:
    p = BridgeProtocol()
    frame = {"op": "publish", "topic": "/t", "msg": {}, "issued": 1.7e9, "later_field": [1]}
    [op] = p.receive_text(json.dumps(frame), 0.0)
    assert op == ops.Publish(topic="/t", msg={}, issued=1.7e9)
    [op] = p.receive_text('{"op":"publish","topic":"/t","msg":{}}', 0.0)
    assert isinstance(op, ops.Publish) and op.issued is None


@given(
    st.one_of(
        st.booleans(), st.text(max_size=8), st.floats(), st.integers(), st.lists(st.integers())
    )
)
def test_any_issued_decodes_to_seconds_or_the_reason_it_is_not(value: Any) -> None:
    p = BridgeProtocol()
    frame = {"op": "publish", "id": "p1", "topic": "/t", "msg": {}, "issued": value}
    try:
        text = json.dumps(frame, allow_nan=True)
    except ValueError:
        return
    [op] = p.receive_text(text, 0.0)  # judged by the session: a stop must still get through
    assert isinstance(op, ops.Publish) and p.frames_to_send() == []
    if op.issued_error is None:
        assert isinstance(op.issued, float) and op.issued > 0
    else:
        assert op.issued is None and "issued" in op.issued_error


def test_an_outgoing_publish_carries_the_commands_issued() -> None:
    p = BridgeProtocol()
    [frame] = p.publish_frames("/cmd_vel", "{}", issued=1700000000.25)
    assert json.loads(frame) == {
        "op": "publish",
        "topic": "/cmd_vel",
        "msg": {},
        "issued": 1700000000.25,
    }
    [plain] = p.publish_frames("/cmd_vel", "{}")
    assert "issued" not in json.loads(plain)


def test_graph_shows_issued_to_callbacks_only_while_delivering() -> None:
    graph = Graph()
    graph.advertise("/a", EMPTY)
    graph.advertise("/b", EMPTY)
    seen: list[tuple[str, float | None]] = []

    def on_a(_msg: dict[str, Any]) -> None:
        seen.append(("a", graph.issued))
        graph.publish("/b", {})  # a callback that publishes in turn (no issued)
        seen.append(("a after b", graph.issued))

    graph.subscribe("/a", on_a)
    graph.subscribe("/b", lambda _m: seen.append(("b", graph.issued)))
    graph.publish("/a", {}, issued=12.5)
    assert seen == [("a", 12.5), ("b", None), ("a after b", 12.5)]
    assert graph.issued is None


async def test_graph_carries_issued_from_another_thread() -> None:
    graph = Graph()
    graph.bind_loop(asyncio.get_running_loop())
    graph.advertise("/a", EMPTY)
    got: list[float | None] = []
    graph.subscribe("/a", lambda _m: got.append(graph.issued))
    worker = threading.Thread(target=lambda: graph.publish("/a", {}, issued=3.0))
    worker.start()
    worker.join()
    await until_async(lambda: got, 5.0, "the publish run on the loop")
    assert got == [3.0]


# -- a real server ----------------------------------------------------------------------------
def _expired_rows(db: Path) -> list[tuple[str, str, str]]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        rows = conn.execute(
            "SELECT commands, action, outcome FROM audit WHERE action = 'expired' ORDER BY id"
        ).fetchall()
    return [(str(c), str(a), str(o)) for c, a, o in rows]


TYPES = {
    "/ardrone/takeoff": EMPTY,
    "/ardrone/land": EMPTY,
    "/cmd_vel": TWIST,
    "/console/reply": "uav_console/Reply",
}


def _taps(srv: RunningServer, topics: list[str]) -> list[tuple[str, float | None]]:
    """What the server's graph delivers on ``topics``, with the ``issued`` each carried."""
    seen: list[tuple[str, float | None]] = []

    def tap(topic: str) -> None:
        def on(_msg: dict[str, Any]) -> None:
            seen.append((topic, srv.graph.issued))

        srv.graph.subscribe(topic, on, type=TYPES[topic])

    for topic in topics:
        srv.call(tap, topic)
    return seen


async def test_a_late_take_off_is_dropped_said_audited_and_a_late_stop_goes_through(
    tmp_path: Path,
) -> None:
    log = AuditLog(tmp_path / "audit.db")
    with running_server(tmp_path, audit=AuditTrail(log)) as srv:
        seen = _taps(srv, ["/ardrone/takeoff", "/ardrone/land", "/console/reply"])
        async with await RawClient.open(srv.url()) as pilot:
            now = time.time()
            await pilot.send(
                {
                    "op": "publish",
                    "id": "late",
                    "topic": "/ardrone/takeoff",
                    "type": EMPTY,
                    "msg": {},
                    "issued": now - 5.0,
                }
            )
            status = await pilot.status("late")
            assert status["level"] == "error", status
            assert "Not flown: 'take off' reached the drone 5." in status["msg"]
            assert "(deadline 2 s)" in status["msg"]
            # a stop issued just as long ago still goes through, with its issued
            await pilot.send(
                {
                    "op": "publish",
                    "id": "land",
                    "topic": "/ardrone/land",
                    "type": EMPTY,
                    "msg": {},
                    "issued": now - 5.0,
                }
            )
            until(lambda: ("/ardrone/land", now - 5.0) in seen, 10.0, "the late land")
            # a take-off in time is delivered, carrying when it was issued
            fresh = time.time()
            await pilot.send(
                {
                    "op": "publish",
                    "id": "fresh",
                    "topic": "/ardrone/takeoff",
                    "type": EMPTY,
                    "msg": {},
                    "issued": fresh,
                }
            )
            until(lambda: ("/ardrone/takeoff", fresh) in seen, 10.0, "the take-off in time")
        assert [t for t, _ in seen].count("/ardrone/takeoff") == 1
        assert [t for t, _ in seen].count("/console/reply") == 1
        [(commands, _, outcome)] = until(
            lambda: _expired_rows(tmp_path / "audit.db"), 10.0, "the audit row"
        )
        assert json.loads(commands) == [{"action": "takeoff"}]
        assert outcome.startswith("expired: delivered 5.") and "past the 2 s deadline" in outcome
    log.close()


async def test_a_late_jog_is_dropped_but_the_end_of_a_jog_is_not(tmp_path: Path) -> None:
    with running_server(tmp_path) as srv:
        seen = _taps(srv, ["/cmd_vel", "/console/reply"])
        async with await RawClient.open(srv.url()) as pilot:
            old = time.time() - 3.0
            for i in range(10):
                await pilot.send(
                    {
                        "op": "publish",
                        "id": f"jog{i}",
                        "topic": "/cmd_vel",
                        "type": TWIST,
                        "msg": JOG,
                        "issued": old,
                    }
                )
            await pilot.send(
                {
                    "op": "publish",
                    "id": "still",
                    "topic": "/cmd_vel",
                    "type": TWIST,
                    "msg": STILL,
                    "issued": old,
                }
            )
            until(lambda: ("/cmd_vel", old) in seen, 10.0, "the late end of the jog")
            status = await pilot.status("jog0")
            assert "Not flown: 'jog'" in status["msg"]
        cmd_vel = [t for t, _ in seen if t == "/cmd_vel"]
        assert cmd_vel == ["/cmd_vel"]  # only the zeros: no late jog reached the graph
        assert [t for t, _ in seen].count("/console/reply") == 1  # said once, not ten times


async def test_subscribers_get_issued_and_a_script_without_it_gets_its_arrival(
    tmp_path: Path,
) -> None:
    with running_server(tmp_path) as srv:
        async with (
            await RawClient.open(srv.url()) as pilot,
            await RawClient.open(srv.url()) as vehicle,
        ):
            await vehicle.send({"op": "subscribe", "topic": "/cmd_vel", "type": TWIST})
            await vehicle.send(
                {"op": "subscribe", "topic": "/console/utterance", "type": "uav_console/Utterance"}
            )
            await pilot.send({"op": "advertise", "topic": "/cmd_vel", "type": TWIST})
            await asyncio.sleep(0)  # nothing to wait for: ops of one client are in order
            issued = time.time() - 0.5
            await pilot.send({"op": "publish", "topic": "/cmd_vel", "msg": JOG, "issued": issued})
            frame = await vehicle.expect_op("publish", topic="/cmd_vel")
            assert frame["issued"] == issued and frame["msg"]["linear"]["x"] == 0.3
            # no issued (a script): stamped on arrival, and carried on
            before = time.time()
            await pilot.send({"op": "publish", "topic": "/cmd_vel", "msg": STILL})
            frame = await vehicle.expect_op("publish", topic="/cmd_vel")
            assert before <= frame["issued"] <= time.time()
            # an utterance is passed on with its issued however old: the dialog judges it
            # (it knows whether it says "land" or "take off")
            utter = {"text": "land", "confidence": 1.0, "source": "text"}
            await pilot.send(
                {
                    "op": "publish",
                    "topic": "/console/utterance",
                    "type": "uav_console/Utterance",
                    "msg": utter,
                    "issued": 1000.0,
                }
            )
            frame = await vehicle.expect_op("publish", topic="/console/utterance")
            assert frame["issued"] == 1000.0
            # milliseconds for seconds: refused with the reason
            await pilot.send(
                {
                    "op": "publish",
                    "id": "ms",
                    "topic": "/cmd_vel",
                    "msg": JOG,
                    "issued": time.time() * 1000,
                }
            )
            status = await pilot.status("ms")
            assert status["level"] == "error" and "milliseconds" in status["msg"]


async def test_a_bad_stamp_refuses_a_motion_command_but_never_holds_a_stop_back(
    tmp_path: Path,
) -> None:
    with running_server(tmp_path) as srv:
        seen = _taps(srv, ["/ardrone/takeoff", "/ardrone/land"])
        async with await RawClient.open(srv.url()) as pilot:
            for topic, fid in (("/ardrone/takeoff", "up"), ("/ardrone/land", "down")):
                await pilot.send(
                    {
                        "op": "publish",
                        "id": fid,
                        "topic": topic,
                        "type": EMPTY,
                        "msg": {},
                        "issued": "yesterday",
                    }
                )
            refused = await pilot.status("up")
            assert refused["level"] == "error" and "Unix seconds" in refused["msg"]
            await pilot.send({"op": "set_level", "level": "warning"})
            await pilot.send(
                {"op": "publish", "id": "down2", "topic": "/ardrone/land", "msg": {}, "issued": -1}
            )
            warned = await pilot.status("down2")
            assert warned["level"] == "warning" and "judged from its arrival" in warned["msg"]
            until(lambda: [t for t, _ in seen].count("/ardrone/land") == 2, 10.0, "both landings")
        assert [t for t, _ in seen].count("/ardrone/takeoff") == 0
