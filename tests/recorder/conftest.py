"""Helpers for the recorder tests: a graph with the vehicle topics, a manual clock."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from server import msgs
from server.graph import Graph
from server.recorder.recorder import Recorder, RecorderConfig

NAVDATA = "ardrone_autonomy/Navdata"


class Clock:
    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def navdata(state: int, battery: float = 80.0) -> dict[str, Any]:
    msg = msgs.default_message(NAVDATA)
    msg["header"] = msgs.header("ardrone_base_link")
    msg["state"] = state
    msg["batteryPercent"] = battery
    return msg


def utterance(text: str) -> dict[str, Any]:
    return {"text": text, "confidence": 1.0, "source": "text", "drone": "uav1"}


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def rig(tmp_path: Path, clock: Clock) -> Iterator[tuple[Graph, Recorder]]:
    graph = Graph()
    config = RecorderConfig(tmp_path / "flights", chunk_s=1.0, idle_s=5.0, preroll_s=10.0)
    rec = Recorder(graph, config, clock=clock, drones=lambda: ["uav1"])
    rec.start(background=False)
    yield graph, rec
    rec.stop()


@pytest.fixture
def srv(tmp_path: Path) -> Iterator[Any]:
    """The rosbridge endpoint alone on a real uvicorn (tests/rosbridge/server_fixture.py)."""
    from tests.rosbridge.server_fixture import running_server

    with running_server(tmp_path) as s:
        yield s
