"""Security at the WebSocket door: tokens, roles, Origin, the auth op and the pilot lease."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus

from tests.support.polling import until_async

from .server_fixture import RunningServer, running_server
from .wsclient import RawClient


async def test_wrong_token_is_refused_at_handshake(srv: RunningServer) -> None:
    with pytest.raises(InvalidStatus) as info:
        await RawClient.open(srv.url(token="not-a-token"))
    assert info.value.response.status_code == 403


async def test_no_token_must_auth_first(srv: RunningServer) -> None:
    c = await RawClient.open(srv.url(token=None))
    await c.send({"op": "subscribe", "id": "s1", "topic": "/rosout", "type": "std_msgs/String"})
    s = await c.status("s1")
    assert s["level"] == "error" and s["msg"].startswith("not authenticated")
    with pytest.raises(ConnectionClosed):
        await c.expect(lambda m: False)
    assert c.ws.close_code == 1008


async def test_auth_op_and_bearer_header(srv: RunningServer) -> None:
    async with await RawClient.open(srv.url(token=None)) as c:
        await c.send({"op": "set_level", "level": "info"})
        await c.send({"op": "auth", "id": "a", "token": srv.observer})
        assert (await c.status("a"))["msg"] == "authenticated as observer"
        await c.send({"op": "call_service", "id": "t", "service": "rosapi/topics"})
        assert (await c.expect_op("service_response", id="t"))["result"] is True
    headers = {"Authorization": f"Bearer {srv.pilot}"}
    async with await RawClient.open(srv.url(token=None), additional_headers=headers) as c:
        await c.send(
            {"op": "advertise", "id": "adv", "topic": "/cmd_vel", "type": "geometry_msgs/Twist"}
        )
        await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
        r = await c.expect_op("service_response", id="t")
        assert "/cmd_vel" in r["values"]["topics"]  # advertised as a pilot: no status error
        assert not [m for m in c.seen if m.get("op") == "status"]


async def test_bad_auth_closes(srv: RunningServer) -> None:
    c = await RawClient.open(srv.url(token=None))
    await c.send({"op": "auth", "id": "a", "token": "guess"})
    assert (await c.status("a"))["msg"] == "auth: invalid token"
    with pytest.raises(ConnectionClosed):
        await c.expect(lambda m: False)
    assert c.ws.close_code == 1008


async def test_observer_may_watch_but_not_command(srv: RunningServer) -> None:
    srv.call(srv.graph.advertise, "/cmd_vel", "geometry_msgs/Twist")
    async with await RawClient.open(srv.url("observer")) as c:
        await c.send({"op": "publish", "id": "p", "topic": "/cmd_vel", "msg": {}})
        assert (await c.status("p"))["msg"] == "observer may not publish to /cmd_vel"
        await c.send({"op": "publish", "id": "p2", "topic": "/uav2/ardrone/takeoff", "msg": {}})
        assert (await c.status("p2"))["msg"] == "observer may not publish to /uav2/ardrone/takeoff"
        await c.send({"op": "advertise", "id": "a", "topic": "/x", "type": "std_msgs/String"})
        assert (await c.status("a"))["msg"] == "observer may not advertise /x"
        await c.send({"op": "advertise_service", "id": "as", "service": "/s", "type": "a/B"})
        assert (await c.status("as"))["msg"] == "observer may not provide the service /s"
        await c.send(
            {
                "op": "call_service",
                "id": "c",
                "service": "/rosapi/set_param",
                "args": {"name": "x", "value": "1"},
            }
        )
        r = await c.expect_op("service_response", id="c")
        assert r["result"] is False and r["values"] == "observer may not call /rosapi/set_param"
        await c.send({"op": "subscribe", "id": "s", "topic": "/cmd_vel"})
        await c.send(
            {
                "op": "call_service",
                "id": "ok",
                "service": "/rosapi/get_param",
                "args": {"name": "x"},
            }
        )
        assert (await c.expect_op("service_response", id="ok"))["result"] is True


async def test_cross_site_origin_is_refused(srv: RunningServer) -> None:
    with pytest.raises(InvalidStatus) as info:
        await RawClient.open(srv.url(), origin="http://evil.example")  # type: ignore[arg-type]
    assert info.value.response.status_code == 403
    same = f"http://127.0.0.1:{srv.port}"
    async with await RawClient.open(srv.url(), origin=same) as c:  # type: ignore[arg-type]
        await c.send({"op": "call_service", "id": "t", "service": "/rosapi/nodes"})
        assert (await c.expect_op("service_response", id="t"))["result"] is True


@pytest.mark.parametrize(
    "origin",
    [
        "https://other.example",  # another site
        "http://console.example",  # the allowed host over another scheme
        "https://console.example:8443",  # ... or on another port
        "https://console.example.evil.example",  # a name that starts like it
        "https://evil.example/https://console.example",  # ... or ends like it
    ],
)
async def test_allow_origin_setting(tmp_path: Path, origin: str) -> None:
    """``allow_origins`` admits exactly the origins it names, and refuses every other."""
    with running_server(tmp_path, allow_origins=("https://console.example",)) as srv:
        allowed = "https://console.example"
        async with await RawClient.open(srv.url(), origin=allowed) as c:  # type: ignore[arg-type]
            await c.send({"op": "call_service", "id": "t", "service": "/rosapi/nodes"})
            assert (await c.expect_op("service_response", id="t"))["result"] is True
        with pytest.raises(InvalidStatus) as info:
            await RawClient.open(srv.url(), origin=origin)  # type: ignore[arg-type]
        assert info.value.response.status_code == 403


async def test_pilot_lease_takeover_tells_the_first(srv: RunningServer) -> None:
    srv.call(srv.graph.advertise, "/cmd_vel", "geometry_msgs/Twist")
    got: list[dict[str, object]] = []
    srv.call(lambda: srv.graph.subscribe("/cmd_vel", got.append))
    twist = {"linear": {"x": 0.1, "y": 0.0, "z": 0.0}, "angular": {"x": 0, "y": 0, "z": 0}}
    async with await RawClient.open(srv.url()) as first, await RawClient.open(srv.url()) as second:
        await first.send({"op": "publish", "id": "f1", "topic": "/cmd_vel", "msg": twist})
        await first.send(
            {
                "op": "call_service",
                "id": "st",
                "service": "/console/lease",
                "args": {"action": "status"},
            }
        )
        st = await first.expect_op("service_response", id="st")
        assert st["values"]["held_by_me"] is True
        await second.send({"op": "publish", "id": "s1", "topic": "/cmd_vel", "msg": twist})
        s = await second.status("s1")
        assert "holds the pilot lease" in s["msg"] and "take_over" in s["msg"]
        await second.send(
            {
                "op": "call_service",
                "id": "take",
                "service": "/console/lease",
                "args": {"action": "acquire", "take_over": True},
            }
        )
        r = await second.expect_op("service_response", id="take")
        assert r["result"] is True and r["values"]["held_by_me"] is True
        lost = await first.status("lease:revoked")
        assert "another pilot took over" in lost["msg"]
        await first.send({"op": "publish", "id": "f2", "topic": "/cmd_vel", "msg": twist})
        assert "holds the pilot lease" in (await first.status("f2"))["msg"]
        await second.send({"op": "publish", "id": "s2", "topic": "/cmd_vel", "msg": twist})
        await second.send({"op": "call_service", "id": "n", "service": "/rosapi/nodes"})
        await second.expect_op("service_response", id="n")
    assert len(got) == 2  # f1 and s2


async def test_version_endpoint(srv: RunningServer) -> None:
    async with httpx.AsyncClient() as http:
        r = await http.get(f"http://127.0.0.1:{srv.port}/version")
    body = r.json()
    assert body["protocol"]["major"] == 2 and body["server"].startswith("uav-console ")


async def test_disconnect_cleans_up(srv: RunningServer) -> None:
    async with await RawClient.open(srv.url()) as c:
        await c.send({"op": "advertise", "topic": "/mine", "type": "std_msgs/String"})
        await c.send({"op": "advertise_service", "service": "/my_srv", "type": "a/B"})
        await c.send({"op": "subscribe", "topic": "/mine"})
        await c.send({"op": "call_service", "id": "t", "service": "/rosapi/topics"})
        await c.expect_op("service_response", id="t")
        assert srv.graph.service_type("/my_srv") == "a/B"
    await until_async(
        lambda: srv.graph.service_type("/my_srv") is None and "/mine" not in srv.graph.topics(),
        10.0,
        "the closed client's service and topic gone",
    )
    assert srv.graph.service_type("/my_srv") is None
    assert "/mine" not in srv.graph.topics()
