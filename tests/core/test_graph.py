"""The in-process graph: topics, latching, bounded queues, services, params, threads."""

from __future__ import annotations

import asyncio
import threading

import pytest

from server.graph import (
    Graph,
    NotFound,
    ServiceError,
    ServiceTimeout,
    TypeMismatch,
    canonical,
)


def test_canonical_names_have_one_leading_slash() -> None:
    assert canonical("rosapi/topics") == "/rosapi/topics"
    assert canonical("//a/b") == "/a/b"
    assert canonical("/a") == "/a"


def test_publish_reaches_every_subscriber_in_order() -> None:
    g = Graph()
    g.advertise("/t", "std_msgs/String")
    got_a: list[str] = []
    got_b: list[str] = []
    g.subscribe("t", lambda m: got_a.append(m["data"]))
    g.subscribe("/t", lambda m: got_b.append(m["data"]))
    for word in ["one", "two", "three"]:
        g.publish("/t", {"data": word})
    assert got_a == got_b == ["one", "two", "three"]


def test_type_mismatch_is_refused() -> None:
    g = Graph()
    g.advertise("/t", "std_msgs/String")
    with pytest.raises(TypeMismatch):
        g.advertise("/t", "std_msgs/Empty")
    with pytest.raises(TypeMismatch):
        g.subscribe("/t", lambda m: None, type="std_msgs/Bool")
    with pytest.raises(TypeMismatch):
        g.publish("/t", {}, type="std_msgs/Empty")


def test_unknown_topic_without_type_is_not_found() -> None:
    g = Graph()
    with pytest.raises(NotFound):
        g.publish("/nobody", {})
    with pytest.raises(NotFound):
        g.subscribe("/nobody", lambda m: None)


def test_latched_topic_gives_last_message_to_late_subscriber() -> None:
    g = Graph()
    g.advertise("/state", "std_msgs/String", latch=True)
    g.publish("/state", {"data": "old"})
    g.publish("/state", {"data": "new"})
    got: list[str] = []
    g.subscribe("/state", lambda m: got.append(m["data"]))
    assert got == ["new"]


def test_queue_subscription_drops_oldest_and_counts() -> None:
    g = Graph()
    g.advertise("/n", "std_msgs/Int32")
    sub = g.subscribe_queue("/n", maxlen=3)
    for i in range(10):
        g.publish("/n", {"data": i})
    assert sub.dropped == 7
    assert [sub.get_nowait()["data"] for _ in range(3)] == [7, 8, 9]  # type: ignore[index]
    assert sub.get_nowait() is None


def test_slow_queue_subscriber_does_not_stall_others() -> None:
    g = Graph()
    g.advertise("/n", "std_msgs/Int32")
    slow = g.subscribe_queue("/n", maxlen=1)
    fast: list[int] = []
    g.subscribe("/n", lambda m: fast.append(m["data"]))
    for i in range(1000):
        g.publish("/n", {"data": i})
    assert len(fast) == 1000
    assert slow.pending() == 1


def test_close_and_drop_owner_remove_subscriptions() -> None:
    g = Graph()
    g.advertise("/t", "std_msgs/String", owner="client1")
    got: list[str] = []
    sub = g.subscribe("/t", lambda m: got.append(m["data"]), owner="client2")
    g.publish("/t", {"data": "a"})
    sub.close()
    g.publish("/t", {"data": "b"}, type="std_msgs/String")
    assert got == ["a"]
    g.subscribe("/t", lambda m: got.append(m["data"]), owner="client3")
    g.drop_owner("client3")
    g.drop_owner("client1")
    assert g.subscribers("/t") == []


async def test_publish_from_another_thread_is_delivered_on_the_loop() -> None:
    g = Graph()
    g.bind_loop(asyncio.get_running_loop())
    g.advertise("/t", "std_msgs/Int32")
    loop_thread = threading.get_ident()
    seen: list[tuple[int, int]] = []
    done = asyncio.Event()

    def on_msg(m: dict) -> None:
        seen.append((m["data"], threading.get_ident()))
        if m["data"] == 99:
            done.set()

    g.subscribe("/t", on_msg)
    worker = threading.Thread(target=lambda: [g.publish("/t", {"data": i}) for i in range(100)])
    worker.start()
    await asyncio.wait_for(done.wait(), 5)
    worker.join()
    assert [v for v, _ in seen] == list(range(100))
    assert {t for _, t in seen} == {loop_thread}


async def test_services_answer_fail_and_time_out() -> None:
    g = Graph()

    async def add(args: dict) -> dict:
        return {"sum": args["a"] + args["b"]}

    async def broken(args: dict) -> dict:
        raise ValueError("no")

    async def slow(args: dict) -> dict:
        await asyncio.Event().wait()  # never answers
        return {}

    g.advertise_service("/add", "test/Add", add)
    g.advertise_service("/broken", "test/Broken", broken)
    g.advertise_service("/slow", "test/Slow", slow)
    assert await g.call_service("add", {"a": 2, "b": 3}) == {"sum": 5}
    with pytest.raises(ServiceError, match="no"):
        await g.call_service("/broken", {})
    with pytest.raises(ServiceTimeout):
        await g.call_service("/slow", {}, timeout=0.01)
    with pytest.raises(NotFound):
        await g.call_service("/missing", {})
    assert g.services() == {"/add": "test/Add", "/broken": "test/Broken", "/slow": "test/Slow"}


def test_params_hold_json_values_only() -> None:
    g = Graph()
    g.set_param("/speed", {"max": 1.5})
    assert g.get_param("speed") == {"max": 1.5}
    assert g.has_param("/speed")
    with pytest.raises(TypeError):
        g.set_param("/bad", object())
    g.delete_param("/speed")
    assert not g.has_param("/speed")
    assert g.param_names() == []
