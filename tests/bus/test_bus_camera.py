"""The camera over a real bus on loopback: a console's embedded router, a vehicle's session
publishing JPEG frames on its camera key, and the console's :class:`BusDroneStack` showing them on
its graph. A frame travels as the JPEG's bytes from the vehicle to the graph (no base64 on the
way, none without a subscriber); a rosbridge client's JSON of it carries the same JPEG as base64."""

from __future__ import annotations

import asyncio
import base64
import json
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any, cast

import cv2
import numpy as np
import pytest
import zenoh

from drone.bus import keys
from drone.bus.commander import BusCommander
from drone.bus.config import client_config
from drone.bus.console import ConsoleBus
from drone.bus.session import open_session
from drone.bus.vehicle import VehicleBus
from drone.deadline import ClockOffset
from server.graph import Graph
from server.msgs import header
from server.nodes.vehicle_node import IMAGE
from server.rosbridge.context import JsonCache
from server.vehicles.bus_remote import BusDroneStack
from server.vehicles.bus_vehicle import BusVehicleSide
from server.vehicles.spec import TopicSpec
from tests.support.loopback import free_port
from tests.support.polling import until_async

NAME = "uav1"
TOPIC = f"/{NAME}/ardrone/image_raw/compressed"


@pytest.fixture(scope="module")
def console(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ConsoleBus]:
    bus = ConsoleBus(
        tmp_path_factory.mktemp("bus-camera") / "bus",
        "default",
        [NAME],
        name="west",
        listen=[f"tcp/127.0.0.1:{free_port()}"],
    )
    bus.start()
    yield bus
    bus.close()


def vehicle_session(bus: ConsoleBus) -> zenoh.Session:
    cred = bus.vehicle_credential(NAME)
    return open_session(
        client_config(connect=list(cred.connect), user=cred.user, password=cred.password)
    )


def jpeg(shade: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", np.full((48, 64, 3), shade, np.uint8))
    assert ok
    return bytes(buf.tobytes())


class Console:
    """A console's graph and the bus stack of ``NAME``; ``seen``: the camera messages published
    on the graph (a tap: it sees them without being a subscriber)."""

    def __init__(self, bus: ConsoleBus) -> None:
        assert bus.session is not None
        self.graph = Graph()
        self.graph.bind_loop(asyncio.get_running_loop())
        self.seen: list[dict[str, Any]] = []
        self.graph.add_tap(lambda topic, _t, msg: self.seen.append(msg) if topic == TOPIC else None)
        self.commander = BusCommander(bus.session, "default", "west")
        self.stack = BusDroneStack(
            self.graph,
            NAME,
            f"/{NAME}",
            self.commander,
            alive=lambda: [NAME],
            pilot=lambda: "pilot",
            topics={},
        )

    def close(self) -> None:
        self.stack.close()
        self.commander.close()


async def frames_until_shown(pub: zenoh.Publisher, frame: bytes, console: Console) -> None:
    """Put ``frame`` until the console's graph shows it (the subscriber reaches the router a
    moment after it is declared; a frame put before that is dropped, as the camera's are)."""

    async def shown() -> bool:
        if not any(m["data"] == frame for m in console.seen):
            pub.put(frame)
            return False
        return True

    await until_async(shown, 20, "the camera frame on the console's graph")


def test_a_bus_frame_reaches_the_graph_as_its_jpeg_and_json_as_its_base64(
    console: ConsoleBus,
) -> None:
    async def main() -> None:
        side = Console(console)
        session = vehicle_session(console)
        pub = session.declare_publisher(keys.camera("default", NAME))
        try:
            frame = jpeg(90)
            await frames_until_shown(pub, frame, side)
            msg = next(m for m in side.seen if m["data"] == frame)
            # the JPEG as it came: nothing encoded it, though nobody but the stack subscribes
            assert type(msg["data"]) is bytes
            assert msg["format"] == "jpeg"
            assert msg["header"]["frame_id"] == "ardrone_base_frontcam"
            assert side.stack.latest_jpeg()[1] == frame
            # what a rosbridge client subscribed to the topic gets (its JSON, as the session
            # makes it): the same JPEG in base64, as before
            text = JsonCache().text(msg)
            assert json.loads(text)["data"] == base64.b64encode(frame).decode("ascii")
        finally:
            pub.undeclare()  # type: ignore[no-untyped-call]
            session.close()
            side.close()

    asyncio.run(main())


def test_a_vehicle_sends_each_frame_as_made_and_the_console_shows_its_stamp(
    console: ConsoleBus,
) -> None:
    """The vehicle side (:class:`BusVehicleSide`) puts each frame of its node's camera topic on
    the bus as it is published, stamped; the console's graph shows the same JPEG with that
    stamp."""

    async def main() -> None:
        side = Console(console)
        cred = console.vehicle_credential(NAME)
        bus = VehicleBus(list(cred.connect), cred.user, cred.password, "default", NAME)
        bus.start()
        host = SimpleNamespace(
            name=NAME, graph=Graph(), clock_offset=ClockOffset(), recording_id=""
        )
        host.graph.bind_loop(asyncio.get_running_loop())
        host.graph.advertise(TOPIC, IMAGE)
        vehicle = BusVehicleSide(cast(Any, host), bus, (TopicSpec(TOPIC, IMAGE),))
        try:
            frame, made = jpeg(200), 1_700_000_000.25

            async def shown() -> bool:
                if any(m["data"] == frame for m in side.seen):
                    return True
                host.graph.publish(
                    TOPIC, {"header": header("cam", made), "format": "jpeg", "data": frame}
                )
                return False

            await until_async(shown, 20, "the vehicle's frame on the console's graph")
            msg = next(m for m in side.seen if m["data"] == frame)
            assert msg["header"]["stamp"] == {"sec": 1_700_000_000, "nanosec": 250_000_000}
            assert side.commander.camera(NAME)[1] == frame
        finally:
            vehicle.close()
            bus.close()
            side.close()

    asyncio.run(main())
