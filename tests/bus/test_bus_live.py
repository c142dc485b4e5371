"""The bus for real: a console's embedded Zenoh router on loopback, vehicles and third-party
clients joining it with their credentials, the router's access control refusing the rest."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from drone.bus import keys
from drone.bus.config import OBSERVER_USER, client_config
from drone.bus.console import ConsoleBus
from drone.bus.credentials import Credentials
from drone.bus.errors import BusConfigError
from drone.bus.payloads import Telemetry, decode_telemetry, encode
from drone.bus.session import DEFAULT_LISTEN, free_listen_endpoint, open_session
from drone.bus.vehicle import VehicleBus
from tests.support.loopback import free_port
from tests.support.polling import wait_for


def telemetry(drone: str, battery: float = 80.0) -> Telemetry:
    return Telemetry(
        drone=drone, stamp=1.0, x=1, y=2, z=1, yaw_deg=0, battery_pct=battery, state="HOVERING"
    )


@pytest.fixture
def console(tmp_path: Path) -> Iterator[ConsoleBus]:
    bus = ConsoleBus(
        tmp_path / "bus",
        "default",
        ["uav1", "uav2"],
        name="console",
        listen=[f"tcp/127.0.0.1:{free_port()}"],
    )
    bus.start()
    yield bus
    bus.close()


def client(bus: ConsoleBus, user: str, password: str | None = None) -> zenoh.Session:
    assert bus.credentials is not None
    pw = bus.credentials.password(user) if password is None else password
    return open_session(client_config(connect=bus.listen, user=user, password=pw))


def vehicle(bus: ConsoleBus, name: str) -> VehicleBus:
    cred = bus.vehicle_credential(name)
    v = VehicleBus(cred.connect, cred.user, cred.password, "default", name)
    v.start()
    return v


def test_a_console_whose_router_id_hashes_to_a_leading_zero_is_on_the_bus(
    tmp_path: Path,
) -> None:
    """``serve --host 127.0.13.1 --port 30029`` is the console ``127-0-13-1-30029``, whose
    name's SHA-256 starts with 0: its router starts, and a vehicle on it is seen."""
    bus = ConsoleBus(
        tmp_path / "bus",
        "default",
        ["uav7"],
        name="127-0-13-1-30029",
        listen=[f"tcp/127.0.0.1:{free_port()}"],
    )
    bus.start()
    try:
        assert bus.router is not None
        assert str(bus.router.info.zid()) == "bb2d10a528463effa1e64c5e5e26a71"
        v = vehicle(bus, "uav7")
        try:
            wait_for(bus.alive, lambda a: a == ["uav7"], 10, "uav7 alive on the bus")
        finally:
            v.close()
    finally:
        bus.close()


def test_a_vehicle_is_alive_and_its_telemetry_arrives(console: ConsoleBus) -> None:
    v = vehicle(console, "uav1")
    try:
        wait_for(console.alive, lambda a: a == ["uav1"], 10, "uav1 alive on the bus")
        key = keys.telemetry("default", "uav1")
        assert v._publisher is not None
        v._publisher.put(encode(telemetry("uav1", 61.0)))
        got = wait_for(lambda: console.latest("uav1"), lambda t: t is not None, 10, "telemetry")
        assert got.battery_pct == 61.0 and key.endswith("uav1/telemetry")
    finally:
        v.close()
    wait_for(console.alive, lambda a: a == [], 10, "uav1 gone when its session closes")


def test_a_vehicle_cannot_publish_under_another_name(console: ConsoleBus) -> None:
    seen: list[str] = []
    watcher = client(console, OBSERVER_USER)
    sub = watcher.declare_subscriber(
        "uavc/default/*/telemetry",
        lambda s: seen.append(decode_telemetry(s.payload.to_bytes()).drone + str(s.key_expr)),
    )
    uav1 = vehicle(console, "uav1")
    try:
        assert uav1.session is not None
        # forged first, then uav1's own three times: the router keeps one session's order
        uav1.session.put(keys.telemetry("default", "uav2"), encode(telemetry("uav2", 3.0)))
        for _ in range(3):
            uav1.session.put(keys.telemetry("default", "uav1"), encode(telemetry("uav1")))
        wait_for(lambda: len(seen), lambda n: n >= 3, 10, "uav1's own telemetry")
        assert seen == ["uav1uavc/default/uav1/telemetry"] * 3
        assert console.latest("uav2") is None
    finally:
        uav1.close()
        sub.undeclare()  # type: ignore[no-untyped-call]
        watcher.close()  # type: ignore[no-untyped-call]


def test_an_observer_publishes_nothing(console: ConsoleBus) -> None:
    observer = client(console, OBSERVER_USER)
    uav1 = vehicle(console, "uav1")
    try:
        observer.put(keys.telemetry("default", "uav1"), encode(telemetry("uav1", 2.0)))
        assert uav1.session is not None
        for _ in range(3):
            uav1.session.put(keys.telemetry("default", "uav1"), encode(telemetry("uav1", 70)))
        wait_for(lambda: console.latest("uav1"), lambda t: t is not None, 10, "uav1 telemetry")
        assert console.latest("uav1").battery_pct == 70  # type: ignore[union-attr]
    finally:
        uav1.close()
        observer.close()  # type: ignore[no-untyped-call]


def test_wrong_or_missing_credentials_are_refused(console: ConsoleBus) -> None:
    with pytest.raises(BusConfigError, match="could not start"):
        client(console, OBSERVER_USER, password="wrong")
    no_auth = {
        "mode": "client",
        "connect": {"endpoints": console.listen},
        "scouting": {"multicast": {"enabled": False}},
    }
    with pytest.raises(BusConfigError):
        open_session(no_auth)


def test_garbage_on_a_telemetry_key_is_refused_and_counted(console: ConsoleBus) -> None:
    uav1 = vehicle(console, "uav1")
    try:
        assert uav1.session is not None
        uav1.session.put(keys.telemetry("default", "uav1"), b"\xff not json")
        uav1.session.put(keys.telemetry("default", "uav1"), encode(telemetry("uav2")))
        uav1.session.put(keys.telemetry("default", "uav1"), encode(telemetry("uav1", 55)))
        wait_for(lambda: console.latest("uav1"), lambda t: t is not None, 10, "good telemetry")
        assert console.refused == 2
    finally:
        uav1.close()


def test_client_files_are_private_and_a_plain_script_watches_with_them(
    console: ConsoleBus,
) -> None:
    """docs/bus.md's example, as a third party writes it: only ``eclipse-zenoh`` and the file."""
    assert console.client_file.stat().st_mode & 0o077 == 0
    assert (console.directory / "pilot.json5").stat().st_mode & 0o077 == 0
    script = textwrap.dedent(
        f"""
        import json, sys, threading, zenoh
        conf = zenoh.Config.from_file({str(console.client_file)!r})
        got = threading.Event()
        seen = {{}}
        def on_sample(sample):
            seen.update(json.loads(sample.payload.to_string()))
            got.set()
        with zenoh.open(conf) as session:
            alive = [str(r.ok.key_expr) for r in session.liveliness().get("uavc/default/*/alive")]
            sub = session.declare_subscriber("uavc/default/*/telemetry", on_sample)
            print("ready", flush=True)
            got.wait(20)
            print(json.dumps({{"alive": alive, "telemetry": seen}}), flush=True)
        """
    )
    uav1 = vehicle(console, "uav1")
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        assert uav1._publisher is not None
        while proc.poll() is None:
            uav1._publisher.put(encode(telemetry("uav1", 42.0)))
            try:
                out, _err = proc.communicate(timeout=0.1)
            except subprocess.TimeoutExpired:
                continue
        out = out or ""
        result = json.loads(out.strip().splitlines()[-1])
    finally:
        proc.kill()
        uav1.close()
    assert result["alive"] == ["uavc/default/uav1/alive"]
    assert result["telemetry"]["battery_pct"] == 42.0 and result["telemetry"]["drone"] == "uav1"


def test_the_default_endpoint_moves_to_the_next_free_port() -> None:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        moved = free_listen_endpoint(f"tcp/127.0.0.1:{port}")
    assert moved != f"tcp/127.0.0.1:{port}" and moved.startswith("tcp/127.0.0.1:")


def test_a_port_whose_connections_linger_in_time_wait_is_free() -> None:
    """A router killed with clients connected leaves its side of each connection in
    ``TIME_WAIT`` on its port; nothing listens there, so a router may listen there again."""
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        with socket.create_connection(("127.0.0.1", port)) as dialler:
            accepted, _ = listener.accept()
            accepted.close()  # the listening side closes first: its end waits in TIME_WAIT
            dialler.recv(1)
    assert free_listen_endpoint(f"tcp/127.0.0.1:{port}") == f"tcp/127.0.0.1:{port}"


def test_a_vehicle_joins_with_its_vehicle_key(tmp_path: Path) -> None:
    """The console's vehicle keys are the bus passwords: one credential per vehicle, also for
    a vehicle from elsewhere whose key was made with ``uav-console vehicle-key``."""
    bus = ConsoleBus(
        tmp_path / "bus",
        "default",
        ["uav1"],
        name="console",
        listen=[f"tcp/127.0.0.1:{free_port()}"],
        vehicle_passwords={"uav1": "uavk_one", "uav7": "uavk_seven"},
    )
    bus.start()
    try:
        assert bus.vehicle_names == ["uav1", "uav7"]
        uav7 = VehicleBus(bus.listen, "vehicle-uav7", "uavk_seven", "default", "uav7")
        uav7.start()
        wait_for(bus.alive, lambda a: a == ["uav7"], 10, "uav7 alive")
        uav7.close()
        with pytest.raises(BusConfigError):
            VehicleBus(bus.listen, "vehicle-uav1", "uavk_seven", "default", "uav1").start()
    finally:
        bus.close()


ROUTER = """
import sys
from pathlib import Path
from drone.bus.console import ConsoleBus
from drone.bus.credentials import Credentials
bus = ConsoleBus(Path(sys.argv[1]), "default", ["uav1"], name="console")
bus.start()
print(bus.listen[0], flush=True)
sys.stdin.read()
"""


def test_a_console_restarted_after_a_kill_listens_where_it_did_and_its_vehicles_rejoin(
    tmp_path: Path,
) -> None:
    """``kill -9`` of a console's router (its vehicle connected): the console restarted on the
    same data directory listens on the endpoint it had, though the killed router's connections
    linger in ``TIME_WAIT`` on that port, and the vehicle, which knows no other, is on its bus
    again."""
    directory = tmp_path / "bus"
    uav1: VehicleBus | None = None
    bus: ConsoleBus | None = None
    # the first free port from the default is taken while the first router starts (another
    # console's, say), and free again when the second one does
    first_free = int(free_listen_endpoint(DEFAULT_LISTEN).rpartition(":")[2])
    with (
        socket.create_server(("127.0.0.1", first_free)) as held,
        subprocess.Popen(
            [sys.executable, "-c", ROUTER, str(directory)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        ) as proc,
    ):
        try:
            assert proc.stdout is not None
            endpoint = proc.stdout.readline().strip()
            assert endpoint.startswith("tcp/127.0.0.1:"), endpoint
            password = Credentials.load_or_create(directory, ["uav1"], {}, None).password(
                "vehicle-uav1"
            )
            uav1 = VehicleBus([endpoint], "vehicle-uav1", password, "default", "uav1")
            uav1.start()
            proc.kill()
            proc.wait()
            held.close()
            bus = ConsoleBus(directory, "default", ["uav1"], name="console")
            assert bus.listen == [endpoint]
            bus.start()
            wait_for(bus.alive, lambda a: a == ["uav1"], 20, "uav1 alive on the restarted console")
        finally:
            proc.kill()
            if uav1 is not None:
                uav1.close()
            if bus is not None:
                bus.close()
