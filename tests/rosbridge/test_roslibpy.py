"""roslibpy (PyPI, unchanged) against our server: topics, latching, services, params, rosapi."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
import roslibpy

from tests.inbox import Inbox
from tests.support.polling import until, until_async

from .server_fixture import RunningServer

TIMEOUT = 10.0


@pytest.fixture
def ros(srv: RunningServer) -> Iterator[roslibpy.Ros]:
    client = roslibpy.Ros(srv.url())
    client.run(timeout=TIMEOUT)
    yield client
    client.close()


def test_publish_from_graph_reaches_roslibpy(srv: RunningServer, ros: roslibpy.Ros) -> None:
    srv.call(srv.graph.advertise, "/chatter", "std_msgs/String")
    inbox = Inbox()
    topic = roslibpy.Topic(ros, "/chatter", "std_msgs/String")
    topic.subscribe(inbox)
    # publish until the subscription is live (subscribe is asynchronous in roslibpy)
    srv.run(_publish_until(srv, inbox, "/chatter", {"data": "hello"}))
    assert inbox.items[0] == {"data": "hello"}


async def _publish_until(srv: RunningServer, inbox: Inbox, topic: str, msg: dict[str, Any]) -> None:
    """Publish until the (asynchronously subscribing) client got one message."""

    def received() -> bool:
        if srv.graph.subscribers(topic):
            srv.graph.publish(topic, msg)
        return bool(inbox.items)

    await until_async(received, TIMEOUT, f"a message on {topic}")


def test_roslibpy_publish_reaches_graph(srv: RunningServer, ros: roslibpy.Ros) -> None:
    got = Inbox()
    srv.call(lambda: srv.graph.subscribe("/from_client", got, type="std_msgs/String"))
    topic = roslibpy.Topic(ros, "/from_client", "std_msgs/String")
    topic.publish(roslibpy.Message({"data": "up"}))
    assert got.wait(1)[0] == {"data": "up"}


def test_latched_topic_reaches_late_subscriber(srv: RunningServer, ros: roslibpy.Ros) -> None:
    pub = roslibpy.Topic(ros, "/latched", "std_msgs/String", latch=True)
    pub.publish(roslibpy.Message({"data": "kept"}))
    second = roslibpy.Ros(srv.url())
    second.run(timeout=TIMEOUT)
    try:
        until(lambda: srv.graph.latched("/latched") is not None, TIMEOUT, "the latched message")
        inbox = Inbox()
        roslibpy.Topic(second, "/latched", "std_msgs/String").subscribe(inbox)
        assert inbox.wait(1)[0] == {"data": "kept"}
    finally:
        second.close()


def test_service_call_and_failure(srv: RunningServer, ros: roslibpy.Ros) -> None:
    async def add(args: dict[str, Any]) -> dict[str, Any]:
        return {"sum": args["a"] + args["b"]}

    srv.call(srv.graph.advertise_service, "/add_two_ints", "example/AddTwoInts", add)
    svc = roslibpy.Service(ros, "/add_two_ints", "example/AddTwoInts")
    assert svc.call(roslibpy.ServiceRequest({"a": 2, "b": 40}), timeout=TIMEOUT) == {"sum": 42}
    # the provider raises (missing key): roslibpy gets result false with the error in values
    with pytest.raises(roslibpy.core.ServiceException, match="failed"):
        svc.call(roslibpy.ServiceRequest({"a": 1}), timeout=TIMEOUT)
    missing = roslibpy.Service(ros, "/nope", "example/Nope")
    with pytest.raises(roslibpy.core.ServiceException, match="does not exist"):
        missing.call(roslibpy.ServiceRequest({}), timeout=TIMEOUT)


def test_client_provided_service_called_by_other_client(
    srv: RunningServer, ros: roslibpy.Ros
) -> None:
    def handler(request: dict[str, Any], response: dict[str, Any]) -> bool:
        response["sum"] = request["a"] + request["b"]
        return True

    provider = roslibpy.Service(ros, "/client_add", "example/AddTwoInts")
    provider.advertise(handler)
    caller = roslibpy.Ros(srv.url())
    caller.run(timeout=TIMEOUT)
    try:
        until(
            lambda: srv.graph.service_type("/client_add") is not None,
            TIMEOUT,
            "/client_add advertised",
        )
        svc = roslibpy.Service(caller, "/client_add", "example/AddTwoInts")
        assert svc.call(roslibpy.ServiceRequest({"a": 3, "b": 4}), timeout=TIMEOUT) == {"sum": 7}
        # the graph sees the provider too
        assert srv.run(srv.graph.call_service("/client_add", {"a": 1, "b": 1}, timeout=5)) == {
            "sum": 2
        }
    finally:
        caller.close()


def test_params_and_rosapi(srv: RunningServer, ros: roslibpy.Ros) -> None:
    srv.call(srv.graph.advertise, "/uav/pose", "geometry_msgs/PoseStamped")
    param = roslibpy.Param(ros, "max_speed")
    param.set({"value": 1.5, "unit": "m/s"}, timeout=TIMEOUT)
    assert param.get(timeout=TIMEOUT) == {"value": 1.5, "unit": "m/s"}
    assert "/max_speed" in ros.get_params()
    param.delete(timeout=TIMEOUT)
    assert param.get(timeout=TIMEOUT) is None
    topics = ros.get_topics()
    assert "/uav/pose" in topics
    assert ros.get_topic_type("/uav/pose") == "geometry_msgs/PoseStamped"
    assert "/uav/pose" in ros.get_topics_for_type("geometry_msgs/PoseStamped")
    assert "/rosapi/topics" in ros.get_services()
    assert ros.get_service_type("/rosapi/topics") == "rosapi/Topics"
    assert ros.get_nodes()
    assert ros.get_time().secs > 1_600_000_000
    details = ros.get_message_details("geometry_msgs/PoseStamped")
    types = [t["type"] for t in details["typedefs"]]
    assert types[0] == "geometry_msgs/PoseStamped" and "std_msgs/Header" in types
