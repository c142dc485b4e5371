"""The graph survives its subscribers and forgets what a gone publisher latched (issue 14)."""

from __future__ import annotations

from typing import Any

import pytest

from server.graph import Graph


def test_a_failing_subscriber_does_not_cost_the_others(caplog: pytest.LogCaptureFixture) -> None:
    g = Graph()
    got: list[Any] = []

    def broken(msg: Any) -> None:
        raise RuntimeError("subscriber bug")

    g.subscribe("/t", broken, type="std_msgs/String", owner="client-a")
    g.subscribe("/t", got.append, type="std_msgs/String")
    g.publish("/t", {"data": "x"})
    g.publish("/t", {"data": "y"})
    assert got == [{"data": "x"}, {"data": "y"}]
    assert "subscriber client-a of /t failed" in caplog.text


def test_latched_message_expires_with_its_publisher() -> None:
    g = Graph()
    g.advertise("/fake", "std_msgs/String", latch=True, owner="client-b")
    g.publish("/fake", {"data": "battery critical"})
    late: list[Any] = []
    g.subscribe("/fake", late.append, owner="watcher")
    assert late == [{"data": "battery critical"}]
    g.drop_owner("client-b")
    later: list[Any] = []
    g.subscribe("/fake", later.append, type="std_msgs/String", owner="watcher2")
    assert later == []
    assert g.latched("/fake") is None
    # the server's own latched topics stay (their publisher never goes)
    g.publish("/server", {"data": "kept"}, type="std_msgs/String")
    g.advertise("/server", "std_msgs/String", latch=True)
    g.publish("/server", {"data": "kept"})
    g.drop_owner("client-b")
    assert g.latched("/server") == {"data": "kept"}
