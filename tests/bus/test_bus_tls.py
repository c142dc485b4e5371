"""The bus over TLS for real: a console's router on ``tls/`` loopback endpoints with a
certificate from the console's local CA; clients verify it with that CA and still log in."""

from __future__ import annotations

import ipaddress
import json
import logging
import os
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from cryptography import x509

from drone.bus import keys
from drone.bus.config import OBSERVER_USER, BusTLS, as_tls, client_config, on_loopback, wants_tls
from drone.bus.console import ConsoleBus
from drone.bus.errors import BusConfigError
from drone.bus.payloads import Telemetry, decode_telemetry, encode
from drone.bus.probe import untrusted
from drone.bus.session import open_session
from drone.bus.vehicle import VehicleBus
from server.cli import main as cli_main
from server.http.tls import ensure_ca
from server.settings import Settings
from server.vehicles.central import bus_tls
from server.vehicles.host import join_bus
from server.vehicles.keys import new_key
from server.vehicles.names import EXIT_CANNOT_START
from tests.isolation.conftest import ROOT, serve
from tests.isolation.conftest import wait_for as poll
from tests.support.loopback import free_port, fresh_address
from tests.support.polling import wait_for
from tests.support.processes import running

SCRIPT = textwrap.dedent(
    """
    import json, sys, threading, zenoh
    samples, done = [], threading.Event()
    def on_sample(sample):
        samples.append(json.loads(sample.payload.to_string()))
        done.set()
    with zenoh.open(zenoh.Config.from_file(sys.argv[1])) as session:
        sub = session.declare_subscriber("uavc/default/uav1/telemetry", on_sample)
        done.wait(30)
        print(json.dumps(samples))
    """
)


def forced_on(data_dir: Path, host: str = "127.0.0.1") -> Settings:
    return Settings(data_dir=data_dir, bus_tls="on", bus_listen=(f"tcp/{host}:{free_port()}",))


@pytest.fixture
def console(tmp_path: Path) -> Iterator[ConsoleBus]:
    settings = forced_on(tmp_path)
    bus = ConsoleBus(
        tmp_path / "bus",
        "default",
        ["uav1"],
        name="first",
        listen=settings.bus_listen,
        tls=bus_tls(settings),
    )
    bus.start()
    yield bus
    bus.close()


def observer(bus: ConsoleBus, *, ca: str | None, connect: list[str] | None = None) -> zenoh.Session:
    assert bus.credentials is not None
    config = client_config(
        connect=connect or bus.listen,
        user=OBSERVER_USER,
        password=bus.credentials.password(OBSERVER_USER),
        ca=ca,
    )
    return open_session(config)


def test_the_router_listens_on_tls_and_the_client_file_alone_receives_telemetry(
    console: ConsoleBus,
) -> None:
    assert console.tls is not None
    assert [e.split("/")[0] for e in console.listen] == ["tls"]
    written = json.loads(console.client_file.read_text())
    assert written["transport"]["link"]["tls"]["root_ca_certificate"] == console.tls.ca
    assert written["connect"]["endpoints"] == console.listen
    # what a third-party script does: nothing but the file
    watcher = zenoh.open(zenoh.Config.from_file(str(console.client_file)))
    seen: list[Telemetry] = []
    sub = watcher.declare_subscriber(
        keys.all_telemetry("default"), lambda s: seen.append(decode_telemetry(s.payload.to_bytes()))
    )
    cred = console.vehicle_credential("uav1")
    assert cred.ca == console.tls.ca
    v = VehicleBus(cred.connect, cred.user, cred.password, "default", "uav1", ca=cred.ca)
    v.start()
    try:
        wait_for(console.alive, lambda a: a == ["uav1"], 10, "uav1 alive over TLS")
        assert v._publisher is not None
        sample = Telemetry(
            drone="uav1", stamp=1.0, x=0, y=0, z=1, yaw_deg=0, battery_pct=55.0, state="HOVERING"
        )

        def published() -> list[Telemetry]:
            assert v._publisher is not None
            v._publisher.put(encode(sample))
            return seen

        got = wait_for(published, lambda s: len(s) > 0, 10, "telemetry at the script")
        assert got[0].battery_pct == 55.0
        assert console.latest("uav1") is not None
    finally:
        v.close()
        sub.undeclare()  # type: ignore[no-untyped-call]
        watcher.close()  # type: ignore[no-untyped-call]


def test_a_client_without_the_ca_or_with_another_ca_cannot_connect(
    console: ConsoleBus, tmp_path: Path
) -> None:
    with pytest.raises(BusConfigError, match="could not start"):
        observer(console, ca=None)  # the system's CAs do not know the console's
    other_ca, _ = ensure_ca(tmp_path / "other")
    with pytest.raises(BusConfigError, match="could not start"):
        observer(console, ca=str(other_ca))
    assert console.tls is not None
    observer(console, ca=console.tls.ca).close()  # type: ignore[no-untyped-call]


def test_a_plain_tcp_client_cannot_connect_to_the_tls_endpoint(console: ConsoleBus) -> None:
    assert console.tls is not None
    tcp = [e.replace("tls/", "tcp/", 1) for e in console.listen]
    with pytest.raises(BusConfigError, match="could not start"):
        observer(console, ca=console.tls.ca, connect=tcp)


def test_the_password_is_still_checked_over_tls(console: ConsoleBus) -> None:
    assert console.tls is not None
    config = client_config(
        connect=console.listen, user=OBSERVER_USER, password="wrong", ca=console.tls.ca
    )
    with pytest.raises(BusConfigError, match="could not start"):
        open_session(config)


def test_a_vehicle_process_joins_with_the_data_dirs_ca_or_says_what_is_missing(
    console: ConsoleBus, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cred = console.vehicle_credential("uav1")
    # the console's data directory: its tls/ca.pem is the default
    here = Settings(data_dir=tmp_path, bus_connect=cred.connect)
    bus = join_bus(here, "uav1", cred.password)
    assert bus is not None and bus.session is not None
    bus.close()
    elsewhere = Settings(data_dir=tmp_path / "elsewhere", bus_connect=cred.connect)
    with caplog.at_level(logging.ERROR):
        assert join_bus(elsewhere, "uav1", cred.password) is None
    assert "--bus-ca" in caplog.text
    given = Settings(
        data_dir=tmp_path / "elsewhere", bus_connect=cred.connect, bus_ca=Path(cred.ca or "")
    )
    bus = join_bus(given, "uav1", cred.password)
    assert bus is not None
    bus.close()


def test_auto_is_tls_off_loopback_only() -> None:
    # Endpoints are classified, never bound: 7447 is the bus's default port (DEFAULT_LISTEN).
    assert not wants_tls("auto", ["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:7447"])
    assert wants_tls("auto", ["tcp/0.0.0.0:7447"])
    assert wants_tls("auto", ["tcp/192.168.1.5:7447"])
    assert wants_tls("auto", ["tls/127.0.0.1:7447"])
    assert wants_tls("on", ["tcp/127.0.0.1:7447"])
    assert not wants_tls("off", ["tcp/0.0.0.0:7447"])
    assert as_tls("tcp/[::]:7447") == "tls/[::]:7447" and as_tls("udp/a:1") == "udp/a:1"
    assert on_loopback("tcp/[::1]:1") and not on_loopback("tcp/[::]:1")


def test_the_certificate_names_the_host_the_bus_listens_on(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, bus_listen=("tcp/192.0.2.7:7447",))  # auto
    tls = bus_tls(settings)
    assert isinstance(tls, BusTLS) and tls.cert is not None
    cert = x509.load_pem_x509_certificate(Path(tls.cert).read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert ipaddress.ip_address("192.0.2.7") in san.get_values_for_type(x509.IPAddress)
    assert tls.ca == str(tmp_path.resolve() / "tls" / "ca.pem")
    assert not (tmp_path / "tls" / "server.pem").exists()  # HTTPS's certificate is its own
    assert bus_tls(Settings(data_dir=tmp_path)) is None  # loopback, auto: plain tcp


def test_serve_with_bus_tls_on_its_vehicles_and_a_script_and_an_outside_vehicle_join(
    tmp_path: Path,
) -> None:
    """``serve --bus-tls on``: the vehicle it spawns joins over TLS, a script given only
    ``client.json5`` receives telemetry, and ``uav-console vehicle --bus-connect tls/…
    --bus-ca FILE`` from another data directory joins too."""
    assert cli_main(["vehicle-key", "uav7", "--data-dir", str(tmp_path / "data")]) == 0
    port = free_port()
    extra = ("--vehicles", "process", "--bus-listen", f"tcp/127.0.0.1:{port}", "--bus-tls", "on")
    env = {"UAVC_SIM_BASE_ADDR": fresh_address()}
    with serve(tmp_path, "sim", extra=extra, env=env) as srv:
        srv.wait_vehicle()
        health = poll(
            lambda: (h := srv.http.get("/api/v1/health").json())["bus"]["alive"] and h,
            "uav1 alive on the TLS bus",
        )
        assert health["bus"]["endpoints"] == [f"tls/127.0.0.1:{port}"]
        out = subprocess.run(
            [sys.executable, "-c", SCRIPT, health["bus"]["client_config"]],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 0, out.stderr
        assert json.loads(out.stdout)[0]["drone"] == "uav1"
        child = {**os.environ, "UAVC_SIM_BASE_ADDR": fresh_address()}
        child.pop("UAVC_VEHICLE_KEY", None)
        child["UAVC_DATA_DIR"] = str(tmp_path / "vehicle-data")  # no CA of its own there
        argv = [sys.executable, "-m", "server", "vehicle", "--name", "uav7", "--drone", "sim"]
        argv += ["--index", "0", "--key-file", str(tmp_path / "data" / "vehicle-keys" / "uav7.key")]
        argv += ["--bus-connect", f"tls/127.0.0.1:{port}"]
        argv += ["--bus-ca", str(tmp_path / "data" / "tls" / "ca.pem")]
        with open(tmp_path / "uav7.log", "wb") as log:
            proc = subprocess.Popen(argv, cwd=ROOT, env=child, stdout=log, stderr=log)
        try:
            poll(
                lambda: "uav7" in srv.http.get("/api/v1/health").json()["bus"]["alive"],
                "uav7 alive on the TLS bus",
                60,
            )
        finally:
            proc.terminate()
            proc.wait(20)


def test_a_console_off_tls_joins_a_tls_router_with_its_ca(
    console: ConsoleBus, tmp_path: Path
) -> None:
    """A second console of the same data directory, listening on plain loopback, joins the
    first one's ``tls/`` router: it verifies it with the CA and is connected to it."""
    settings = Settings(
        data_dir=tmp_path,
        bus_listen=(f"tcp/127.0.0.1:{free_port()}",),
        bus_connect=tuple(console.listen),
    )
    tls = bus_tls(settings)
    assert tls is not None and tls.cert is None and console.tls is not None
    assert tls.ca == console.tls.ca
    second = ConsoleBus(
        tmp_path / "bus",
        "default",
        [],
        name="second",
        listen=settings.bus_listen,
        connect=settings.bus_connect,
        tls=tls,
    )
    second.start()
    try:
        assert second.listen == list(settings.bus_listen)  # as given: tcp/ on loopback
        assert second.session is not None and console.session is not None
        wait_for(
            lambda: [j.joined for j in second.joins()],
            lambda up: up == [True],
            10,
            "the second console joined the first's router",
        )
        session = second.session

        def consoles() -> set[str]:
            replies = session.liveliness().get(keys.all_consoles_alive("default"), timeout=5)
            return {str(r.ok.key_expr) for r in replies if r.ok is not None}

        wait_for(
            consoles,
            lambda seen: "uavc/default/console/first/alive" in seen,
            10,
            "the first console's presence at the second, over TLS",
        )
    finally:
        second.close()


def test_a_vehicle_refuses_a_router_its_ca_does_not_trust_and_joins_one_it_does(
    tmp_path: Path,
) -> None:
    """``uav-console vehicle --bus-connect tls/… --bus-ca FILE`` from another data directory:
    with another CA it stops at once, in one line naming the router, why, and ``--bus-ca``
    (Zenoh alone would say "Unable to connect", as for a router not up, and dial it forever);
    with the console's CA it joins."""
    key = new_key()
    settings = forced_on(tmp_path / "console")
    bus = ConsoleBus(
        tmp_path / "console" / "bus",
        "default",
        [],
        name="first",
        listen=settings.bus_listen,
        tls=bus_tls(settings),
        vehicle_passwords={"uav1": key},
    )
    bus.start()
    try:
        assert bus.tls is not None
        [endpoint] = bus.listen
        other_ca, _ = ensure_ca(tmp_path / "other")
        assert untrusted(endpoint, bus.tls.ca) is None
        assert "does not trust" in (untrusted(endpoint, str(other_ca)) or "")
        assert untrusted(f"tls/127.0.0.1:{free_port()}", str(other_ca)) is None  # not up
        env = {**os.environ, "UAVC_SIM_BASE_ADDR": fresh_address(), "UAVC_VEHICLE_KEY": key}
        env["UAVC_DATA_DIR"] = str(tmp_path / "vehicle")
        env.pop("UAVC_TOKEN", None)
        argv = [sys.executable, "-m", "server", "vehicle", "--name", "uav1", "--drone", "sim"]
        argv += ["--bus-connect", endpoint]
        refused = subprocess.run(
            [*argv, "--bus-ca", str(other_ca)],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert refused.returncode == EXIT_CANNOT_START, refused.stderr
        [line] = [ln for ln in refused.stderr.splitlines() if ln.startswith("uav-console")]
        assert f"the bus router at {endpoint} presents a certificate" in line
        assert "does not trust" in line and "--bus-ca" in line
        assert bus.alive() == []
        with running([*argv, "--bus-ca", bus.tls.ca], tmp_path / "uav1.log", env) as proc:
            wait_for(
                lambda: proc.poll() is None and bus.alive(),
                lambda alive: alive == ["uav1"],
                90,
                "uav1 on the TLS bus with the console's CA",
            )
    finally:
        bus.close()
