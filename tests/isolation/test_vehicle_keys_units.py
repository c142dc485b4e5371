"""Vehicle keys, what a console shows of each vehicle, the reply check, and the lease rule that
judges what a pilot sends whatever door it enters by (issue 26 "Vehicles have their own
credentials"). Real files in a temporary data directory; no sockets (see test_vehicle_keys.py
and tests/bus for those)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.cli import main as cli_main
from server.http.security import CONTROL_TOPIC_RE, SERVER_TOPIC_RE, Role, Security, TokenStore
from server.settings import Settings
from server.vehicles.central import bus_topics
from server.vehicles.errors import VehicleKeyError
from server.vehicles.keys import (
    KEY_ENV,
    RESCAN_S,
    VehicleKeys,
    check_name,
    key_from,
    new_key,
    parse_key,
    read_key_file,
    vehicle_env,
)
from server.vehicles.relay import checked_reply
from tests.support.loopback import free_port


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


# ------------------------------------------------------------------------------ the key store


def test_a_key_is_made_once_private_and_names_its_vehicle(tmp_path: Path) -> None:
    keys = VehicleKeys(tmp_path)
    k = keys.ensure("uav1")
    assert k.path == tmp_path / "vehicle-keys" / "uav1.key"
    assert stat.S_IMODE(os.stat(k.path).st_mode) == 0o600
    assert stat.S_IMODE(os.stat(k.path.parent).st_mode) == 0o700
    assert k.secret.startswith("uavk_") and k.secret not in repr(k)
    assert keys.ensure("uav1") == k  # kept, not remade
    other = keys.ensure("uav2")
    assert other.secret != k.secret
    assert keys.vehicle_for(k.secret) == "uav1"
    assert keys.vehicle_for(other.secret) == "uav2"
    assert keys.vehicle_for(k.secret + "x") is None
    assert keys.vehicle_for("") is None and keys.vehicle_for(None) is None
    assert keys.vehicle_for("\ud800") is None  # a lone surrogate from JSON: no match, no crash
    assert [x.name for x in keys.all()] == ["uav1", "uav2"]


def test_rotated_and_revoked_keys_stop_opening_within_the_rescan(tmp_path: Path) -> None:
    clock = Clock()
    console = VehicleKeys(tmp_path, clock=clock)
    operator = VehicleKeys(tmp_path)  # the CLI, another process, while the console runs
    old = operator.ensure("uav7")
    assert console.vehicle_for(old.secret) == "uav7"
    new = operator.rotate("uav7")
    clock.t += RESCAN_S
    assert console.vehicle_for(old.secret) is None
    assert console.vehicle_for(new.secret) == "uav7"
    assert operator.revoke("uav7") and not operator.revoke("uav7")
    clock.t += RESCAN_S
    assert console.vehicle_for(new.secret) is None


@pytest.mark.parametrize("name", ["", "../uav1", "uav-1", "1uav", "a/b", "uav 1", "x" * 65])
def test_bad_vehicle_names_are_refused(tmp_path: Path, name: str) -> None:
    with pytest.raises(VehicleKeyError, match="bad vehicle name"):
        VehicleKeys(tmp_path).ensure(name)
    assert not (tmp_path / "vehicle-keys").exists()  # nothing written, anywhere
    assert list(tmp_path.iterdir()) == []


def test_check_name_accepts_topic_names() -> None:
    assert check_name("uav1") == "uav1"
    assert check_name("Scout_2") == "Scout_2"


def test_a_pilot_token_or_garbage_is_not_a_vehicle_key(tmp_path: Path) -> None:
    pilot = TokenStore(tmp_path).pilot_token
    with pytest.raises(VehicleKeyError, match=r"not a vehicle key.*does not open"):
        parse_key(pilot, "UAVC_VEHICLE_KEY")
    with pytest.raises(VehicleKeyError, match=r"is empty.*vehicle-key NAME"):
        parse_key("  \n", "the file")
    with pytest.raises(VehicleKeyError, match="several lines"):
        parse_key(new_key() + "\n" + new_key(), "the file")
    assert parse_key(f"  {(k := new_key())}\n", "x") == k


@given(st.text(max_size=200))
def test_parse_key_returns_a_key_or_raises_the_documented_error(text: str) -> None:
    try:
        key = parse_key(text, "x")
    except VehicleKeyError:
        return
    assert key == text.strip() and key.startswith("uavk_")


def test_the_vehicle_reads_its_key_from_the_file_or_the_environment(tmp_path: Path) -> None:
    k = VehicleKeys(tmp_path).ensure("uav3")
    assert read_key_file(k.path) == k.secret
    assert key_from(k.path, {}) == k.secret
    assert key_from(None, {KEY_ENV: k.secret}) == k.secret
    with pytest.raises(VehicleKeyError, match="--key-file PATH or UAVC_VEHICLE_KEY"):
        key_from(None, {})
    with pytest.raises(VehicleKeyError, match="no vehicle key file"):
        read_key_file(tmp_path / "missing.key")
    env = vehicle_env({"PATH": "/bin"}, VehicleKeys(tmp_path), "uav3")
    assert env == {"PATH": "/bin", KEY_ENV: k.secret}


def test_vehicle_key_command_makes_prints_rotates_and_revokes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = str(tmp_path)
    assert cli_main(["vehicle-key", "uav7", "uav8", "--data-dir", data]) == 0
    out = capsys.readouterr().out
    assert "uav7's vehicle key (made now)" in out and "--key-file uav7.key" in out
    secret = (tmp_path / "vehicle-keys" / "uav7.key").read_text().strip()
    assert secret not in out  # the key stays out of the terminal unless asked
    assert cli_main(["vehicle-key", "uav7", "--data-dir", data, "--print"]) == 0
    assert capsys.readouterr().out.strip() == secret
    assert cli_main(["vehicle-key", "uav7", "--data-dir", data, "--rotate", "--print"]) == 0
    assert capsys.readouterr().out.strip() != secret
    assert cli_main(["vehicle-key", "uav7", "--data-dir", data, "--revoke"]) == 0
    assert "removed" in capsys.readouterr().out
    assert not (tmp_path / "vehicle-keys" / "uav7.key").exists()
    assert cli_main(["vehicle-key", "../x", "--data-dir", data]) == 2
    assert "bad vehicle name" in capsys.readouterr().err
    assert cli_main(["vehicle-key", "a1", "a2", "--data-dir", data, "--print"]) == 2


def test_a_vehicle_without_its_key_stops_with_the_way_to_get_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv(KEY_ENV, raising=False)
    argv = ["vehicle", "--bus-connect", f"tcp/127.0.0.1:{free_port()}", "--name", "uav1"]
    assert cli_main(argv) == 2
    assert "vehicle-key NAME" in capsys.readouterr().err
    pilot = TokenStore(tmp_path).pilot_token
    monkeypatch.setenv(KEY_ENV, pilot)  # the pilot token where the key belongs
    assert cli_main(argv) == 2
    assert "not a vehicle key" in capsys.readouterr().err


# ------------------------------------------------------------------------------ scope


@pytest.mark.parametrize(("name", "prefix"), [("uav1", ""), ("uav2", "/uav2")])
def test_what_a_vehicle_shows_is_its_own_drone_and_nothing_of_the_server(
    name: str, prefix: str
) -> None:
    """The topics a console shows of a vehicle on the bus (any other is dropped): its own
    drone's and its own ``/NAME/vehicle/*``, never a server topic or a command."""
    topics = set(bus_topics(name, prefix))
    assert {f"{prefix}/ardrone/navdata", f"{prefix}/mavros/state", f"{prefix}/uav/pose"} <= topics
    own = {"alarm", "task_event", "reply", "info", "telemetry"}
    assert {f"/{name}/vehicle/{t}" for t in own} <= topics
    assert f"/{name}/vehicle/state" not in topics  # it runs no dialog
    assert f"/{name}/fleet/ltm_status" in topics
    for topic in topics:
        assert not SERVER_TOPIC_RE.match(topic), topic
        assert topic.startswith((f"/{name}/", f"{prefix}/"))
    commands = {f"{prefix}/cmd_vel", f"{prefix}/ardrone/takeoff", f"{prefix}/ardrone/land"}
    assert not commands & topics
    assert all(CONTROL_TOPIC_RE.match(c) for c in commands)


def test_pilots_may_not_speak_or_answer_as_a_vehicle(tmp_path: Path) -> None:
    sec = Security(Settings(data_dir=tmp_path), TokenStore(tmp_path))
    assert not sec.can_publish(Role.PILOT, "/uav1/vehicle/reply")  # laundered to /console/reply
    assert not sec.can_publish(Role.PILOT, "/uav1/vehicle/info")
    assert not sec.can_provide(Role.PILOT, "/uav1/vehicle/control")
    # nor as its LTM: a status would put a drone in the CTM's plans, a service take its plans
    assert not sec.can_publish(Role.PILOT, "/uav1/fleet/ltm_status")
    assert not sec.can_provide(Role.PILOT, "/uav1/fleet/flight_plan")
    assert sec.can_publish(Role.PILOT, "/uav1/ardrone/takeoff")  # a pilot's own commands stay


# ------------------------------------------------------------------------------ replies


def test_the_console_relays_a_reply_only_as_its_own_vehicles() -> None:
    msg = {"text": "Not flown: 'take off' reached the drone 3.1 s late.", "level": "warn"}
    out, _ = checked_reply({**msg, "drone": ""}, "uav1")
    assert out is not None and out["drone"] == "uav1"
    assert checked_reply({**msg, "drone": "uav1"}, "uav1")[0] is not None
    out, why = checked_reply({**msg, "drone": "uav2"}, "uav1")
    assert out is None and "uav2" in why
    out, why = checked_reply({**msg, "level": "console"}, "uav1")
    assert out is None and "level" in why
    assert checked_reply({**msg, "text": "x" * 5000}, "uav1")[0] is None


# ------------------------------------------------------------------------------ the lease


def test_the_lease_judges_what_a_pilot_sends(tmp_path: Path) -> None:
    sec = Security(Settings(data_dir=tmp_path), TokenStore(tmp_path))
    sec.actions_of = lambda text: {"land"} if "land" in text else {"move"} if text else set()
    zero = {"linear": {"x": 0, "y": 0.0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 0}}
    assert sec.lease_exempt("/uav1/cmd_vel", zero)  # hover: any pilot
    assert sec.lease_exempt("/cmd_vel", {})
    assert not sec.lease_exempt("/cmd_vel", {"linear": {"x": 0.3}})  # jog: the lease
    assert not sec.lease_exempt("/cmd_vel", {"linear": {"x": True}})
    assert not sec.lease_exempt("/cmd_vel", {"linear": {"x": float("nan")}})
    assert not sec.lease_exempt("/cmd_vel", {"linear": "0"})
    assert not sec.lease_exempt("/cmd_vel", [])
    utt = "/console/utterance"
    assert sec.lease_exempt(utt, {"text": "uav2 land"})
    assert not sec.lease_exempt(utt, {"text": "move forward"})
    assert not sec.lease_exempt(utt, {"text": ""})  # "yes" to a question: the lease
    assert not sec.lease_exempt(utt, {"text": 3})
    assert not sec.lease_exempt("/ardrone/takeoff", {})
    sec.actions_of = None
    assert not sec.lease_exempt(utt, {"text": "land"})


def test_refusal_messages_keep_their_shape(tmp_path: Path) -> None:
    sec = Security(Settings(data_dir=tmp_path), TokenStore(tmp_path))
    assert sec.refusal(Role.OBSERVER, "publish to", "/cmd_vel") == (
        "observer may not publish to /cmd_vel"
    )
    assert sec.refusal(None, "call", "/x") == "an unauthenticated client may not call /x"
