"""Unit tests of the isolation parts: the central-loss watch, the safety door's URLs and
origins (the door itself: test_door.py), the children's environment."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.graph import Graph
from server.settings import Settings, SettingsError
from server.vehicles.central import child_env
from server.vehicles.door import advertised_url, page_origin
from server.vehicles.watch import CentralWatch, LossAction

# ------------------------------------------------------------------------------ CentralWatch


def test_watch_hovers_then_lands_once_per_silence() -> None:
    w = CentralWatch(hover_after_s=1.0, land_after_s=5.0)
    assert w.step(0.5, 0.0, flying=True) is None
    assert w.step(1.0, 0.0, flying=True) is LossAction.HOVER
    assert w.step(2.0, 0.0, flying=True) is None  # once
    assert w.step(5.0, 0.0, flying=True) is LossAction.LAND
    assert w.step(9.0, 0.0, flying=True) is None
    assert w.step(9.1, 9.0, flying=True) is None  # heard again: the silence is over
    assert w.step(10.5, 9.0, flying=True) is LossAction.HOVER  # a new silence
    assert w.losses == 2


def test_watch_does_nothing_on_the_ground() -> None:
    w = CentralWatch(hover_after_s=1.0, land_after_s=2.0)
    assert [w.step(t, 0.0, flying=False) for t in (1.0, 2.0, 3.0)] == [None, None, None]


def test_watch_rejects_inverted_times() -> None:
    with pytest.raises(ValueError):
        CentralWatch(hover_after_s=3.0, land_after_s=2.0)


# ------------------------------------------------------------------------------ safety door URLs


def test_the_advertised_url_names_the_host_the_page_came_from() -> None:
    # bound to loopback: as bound (the page is on this machine); URLs are parsed, never bound
    assert advertised_url("ws://127.0.13.2:5001", "localhost:8000") == "ws://127.0.13.2:5001"
    # bound to every interface or a LAN address: the host the request named, the port's own
    # scheme (ws/wss) and port
    assert advertised_url("wss://0.0.0.0:5001", "192.168.1.7:8000") == "wss://192.168.1.7:5001"
    assert advertised_url("wss://[::]:5001", "[fe80::2]:8000") == "wss://[fe80::2]:5001"
    assert advertised_url("wss://192.168.1.7:5001", "laptop:8000") == "wss://laptop:5001"
    # nothing usable
    assert advertised_url("ws://0.0.0.0:5001", None) is None
    assert advertised_url("ws://0.0.0.0:5001", "bad host") is None
    assert advertised_url("ws://192.168.1.7:5001", None) == "ws://192.168.1.7:5001"
    assert advertised_url(None, "192.168.1.7:8000") is None


def test_the_console_page_on_the_requested_host_is_an_allowed_origin() -> None:
    assert page_origin("https://192.168.1.7:8000", "192.168.1.7:5001", 8000)
    assert page_origin("https://laptop:8000", "laptop:5001", 8000)  # a bare host name
    assert not page_origin("https://192.168.1.7:9000", "192.168.1.7:5001", 8000)  # other port
    assert not page_origin("https://192.168.1.8:8000", "192.168.1.7:5001", 8000)  # other host
    # a DNS name could be an attacker's, re-pointed at this address (DNS rebinding)
    assert not page_origin("http://evil.example:8000", "evil.example:5001", 8000)
    assert not page_origin("https://192.168.1.7:8000", None, 8000)
    assert not page_origin("https://192.168.1.7:8000.evil", "192.168.1.7:5001", 8000)


# ------------------------------------------------------------------------------ settings


def test_child_env_passes_settings_and_the_token_only_as_uavc_token(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path, token="secret", allow_origins=("a", "b"), world="outdoor")
    env = child_env(s, "secret")
    assert env["UAVC_TOKEN"] == "secret"
    assert env["UAVC_WORLD"] == "outdoor" and env["UAVC_ALLOW_ORIGINS"] == "a,b"
    assert Settings.from_env(env).world == "outdoor"


def test_unknown_vehicles_mode_is_refused(tmp_path: Path) -> None:
    from server.runtime import Runtime

    with pytest.raises(SettingsError, match="inline or process"):
        Runtime(Settings(data_dir=tmp_path, vehicles="threads"))


def test_serve_says_where_each_flight_stack_runs() -> None:
    from server.vehicles.central import flight_stacks_line

    assert flight_stacks_line(["uav1"], []) == "uav1 in its own process"
    assert flight_stacks_line(["uav1", "uav2"], []) == "uav1, uav2 each in its own process"
    assert flight_stacks_line([], ["uav1"]) == "uav1 in the web process (--vehicles inline)"
    assert flight_stacks_line([], []) == "no drone"


def test_a_mavlink_vehicle_shares_mavros_topics_not_a_camera() -> None:
    from server.vehicles.host import shared_topics

    ardrone = {t.name for t in shared_topics("uav2", "/uav2")}
    mavlink = {t.name: t for t in shared_topics("uav2", "/uav2", mavlink=True)}
    assert "/uav2/ardrone/image_raw/compressed" in ardrone
    assert "/uav2/ardrone/image_raw/compressed" not in mavlink
    assert "/uav2/ardrone/navdata" not in mavlink
    assert mavlink["/uav2/mavros/state"].latch
    assert not mavlink["/uav2/mavros/local_position/pose"].latch
    assert {"/uav2/uav/pose", "/uav2/uav/task", "/uav2/vehicle/telemetry"} <= set(mavlink)
    # the signing secret reaches a MAVLink vehicle process (as the token does: environment only)
    env = child_env(Settings(mavlink_key="ab" * 32, mavlink_sim_port=5761), "secret")  # not bound
    assert env["UAVC_MAVLINK_KEY"] == "ab" * 32 and env["UAVC_MAVLINK_SIM_PORT"] == "5761"


def test_serve_refuses_a_bad_mavlink_entry_before_spawning_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from server.cli import main

    argv = ["serve", "--drone", "sim,tcp:nohost", "--fleet", "2", "--data-dir", str(tmp_path)]
    assert main([*argv, "--vehicles", "process"]) == 2
    assert "'tcp:nohost' is not a MAVLink connection string" in capsys.readouterr().err


def test_real_time_priorities_are_checked_up_front() -> None:
    """A priority the OS cannot take, or vehicle threads that could hold the control thread off
    the CPU, is refused where the settings are read (``serve`` exits 2 with the message)."""
    with pytest.raises(
        SettingsError, match=r"control_rt_priority must be 0 \(off\) to 99, not 100"
    ):
        Settings(control_rt_priority=100)
    with pytest.raises(SettingsError, match=r"vehicle_rt_priority must be 0 \(off\) to 99, not -1"):
        Settings.from_env({"UAVC_VEHICLE_RT_PRIORITY": "-1"})
    with pytest.raises(SettingsError, match=r"must be above vehicle_rt_priority \(5\)"):
        Settings(control_rt_priority=5, vehicle_rt_priority=5)
    with pytest.raises(SettingsError, match="UAVC_CONTROL_RT_PRIORITY='high' is not a valid"):
        Settings.from_env({"UAVC_CONTROL_RT_PRIORITY": "high"})
    assert Settings(control_rt_priority=0, vehicle_rt_priority=0).control_rt_priority == 0  # off


def test_serve_refuses_an_unknown_vehicles_mode(tmp_path: Path) -> None:
    import os
    import subprocess
    import sys

    from tests.isolation.conftest import ROOT

    env = {**os.environ, "UAVC_VEHICLES": "threads"}
    argv = [sys.executable, "-m", "server", "serve", "--drone", "none", "--data-dir", str(tmp_path)]
    out = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "inline or process" in out.stderr


def test_a_remote_drone_serves_the_jpeg_its_camera_topic_carries() -> None:
    """The MJPEG route's frame of a vehicle-process drone: the bytes on the graph, as they are."""
    from server.vehicles.remote import RemoteDroneStack

    g = Graph()
    stack = RemoteDroneStack(g, "uav1", "/uav1")
    assert stack.latest_jpeg() == (-1, None)
    frame = b"\xff\xd8 a jpeg \xff\xd9"
    image = {"header": {"frame_id": "cam"}, "format": "jpeg", "data": frame}
    g.publish("/uav1/ardrone/image_raw/compressed", image)
    assert stack.latest_jpeg() == (1, frame)
    stack.close()
