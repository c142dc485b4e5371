"""The bus's key space and payloads: sans-I/O, every input parses or is refused with a reason."""

from __future__ import annotations

import contextlib
import json
import math
from pathlib import Path

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from drone.bus import keys
from drone.bus.config import access_control, client_config, router_id, vehicle_user
from drone.bus.credentials import Credentials
from drone.bus.errors import BusConfigError, KeySegmentError, PayloadError
from drone.bus.payloads import (
    Telemetry,
    decode_camera_stamp,
    decode_telemetry,
    encode,
    encode_camera_stamp,
)
from drone.bus.session import DEFAULT_LISTEN


def test_documented_keys() -> None:
    assert keys.telemetry("default", "uav1") == "uavc/default/uav1/telemetry"
    assert keys.alive("default", "uav2") == "uavc/default/uav2/alive"
    assert keys.command("site-b", "uav7") == "uavc/site-b/uav7/cmd"
    assert keys.central_alive("default") == "uavc/default/central/alive"
    assert keys.central_missions("default") == "uavc/default/central/missions"
    assert keys.drone_of("uavc/default/uav3/telemetry") == "uav3"
    assert keys.drone_of("uavc/default/central/alive") is None


@pytest.mark.parametrize("name", ["", "a/b", "*", "**", "uav$1", "a b", "x" * 65, "é"])
def test_names_that_cannot_be_a_segment_are_refused(name: str) -> None:
    with pytest.raises(KeySegmentError):
        keys.telemetry("default", name)


def test_central_is_not_a_drone_name() -> None:
    with pytest.raises(KeySegmentError, match="central"):
        keys.telemetry("default", "central")


@given(st.text(max_size=80))
def test_any_name_is_a_segment_or_refused(name: str) -> None:
    try:
        key = keys.alive("default", name)
    except KeySegmentError:
        return
    assert key.split("/") == ["uavc", "default", name, "alive"]


finite = st.floats(allow_nan=False, allow_infinity=False, width=32)


@given(
    st.builds(
        Telemetry,
        drone=st.from_regex(keys.SEGMENT, fullmatch=True),
        stamp=finite,
        x=finite,
        y=finite,
        z=finite,
        yaw_deg=finite,
        battery_pct=finite,
        state=st.sampled_from(["LANDED", "FLYING", "HOVERING"]),
        link_ok=st.booleans(),
        flying=st.booleans(),
    )
)
def test_telemetry_round_trip(message: Telemetry) -> None:
    assert decode_telemetry(encode(message)) == message


@given(st.binary(max_size=300))
def test_garbage_telemetry_is_refused(data: bytes) -> None:
    with contextlib.suppress(PayloadError):
        decode_telemetry(data)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"{", "not JSON"),
        (b"[]", "payload"),
        (json.dumps({"drone": "uav1"}).encode(), "stamp"),
        (b'{"v": 2, "drone": "uav1"}', "v"),
        (b"x" * 70000, "bytes"),
    ],
)
def test_bad_telemetry_says_why(payload: bytes, reason: str) -> None:
    with pytest.raises(PayloadError, match=reason):
        decode_telemetry(payload)


def test_non_finite_telemetry_is_refused() -> None:
    good = Telemetry(drone="uav1", stamp=1.0, x=0, y=0, z=0, yaw_deg=0, battery_pct=50, state="X")
    raw = json.loads(encode(good))
    raw["x"] = math.inf
    with pytest.raises(PayloadError, match="x"):
        decode_telemetry(json.dumps(raw).encode())


def test_acl_gives_each_vehicle_its_own_keys_only() -> None:
    acl = access_control("default", ["uav1", "uav2"])
    assert acl["default_permission"] == "deny"
    own = {r["id"]: r["key_exprs"] for r in acl["rules"] if r["id"].startswith("own-")}
    assert own == {"own-uav1": ["uavc/default/uav1/**"], "own-uav2": ["uavc/default/uav2/**"]}
    subjects = {s["id"]: s.get("usernames") for s in acl["subjects"]}
    assert subjects["vehicle-uav1"] == [vehicle_user("uav1")]


def test_client_configuration_never_scouts() -> None:
    cfg = client_config(connect=[DEFAULT_LISTEN], user="observer", password="p")
    assert cfg["scouting"]["multicast"]["enabled"] is False
    assert cfg["mode"] == "client"


SEGMENTS = st.from_regex(keys.SEGMENT, fullmatch=True)


@given(SEGMENTS, SEGMENTS)
def test_every_console_name_gives_a_router_id_zenoh_takes(fleet: str, console: str) -> None:
    """Zenoh refuses an id with a leading 0 ("Leading 0s are not valid"): one console name in
    16 hashes to one (``serve`` on 127.0.13.1:30029 is ``127-0-13-1-30029``), and that
    console's bus did not start."""
    zid = router_id(fleet, console)
    zenoh.Config.from_json5(json.dumps({"id": zid}))
    assert zid == router_id(fleet, console) and len(zid) <= 32


def test_router_ids_are_stable_and_differ_by_name() -> None:
    assert router_id("default", "127-0-13-1-30029") == "bb2d10a528463effa1e64c5e5e26a71"
    assert router_id("default", "console-a") != router_id("default", "console-b")
    assert router_id("default", "a") != router_id("site-b", "a")


def test_a_console_takes_another_consoles_bus_credentials_but_keeps_its_vehicle_keys(
    tmp_path: Path,
) -> None:
    """``serve --bus-credentials FILE``: this console's bus users and passwords become the
    other's (so its joiner is let in there), kept for its next start; its own vehicle keys win."""
    first = Credentials.load_or_create(tmp_path / "a", ["uav1", "uav2"])
    own = Credentials.load_or_create(tmp_path / "b", [], {"uav2": "uavk_b2"})
    assert own.password("console") != first.password("console")
    shared = Credentials.load_or_create(tmp_path / "b", [], {"uav2": "uavk_b2"}, first.path)
    for user in ("console", "observer", "pilot", "vehicle-uav1"):
        assert shared.password(user) == first.password(user), user
    assert shared.password("vehicle-uav2") == "uavk_b2"
    again = Credentials.load_or_create(tmp_path / "b", [], {"uav2": "uavk_b2"})
    assert again.users == shared.users
    with pytest.raises(BusConfigError, match="the shared bus credentials"):
        Credentials.load_or_create(tmp_path / "b", [], shared=tmp_path / "missing.txt")
    (tmp_path / "bad.txt").write_text("console\n")
    with pytest.raises(BusConfigError, match=r"bad\.txt:1: not user:password"):
        Credentials.load_or_create(tmp_path / "b", [], shared=tmp_path / "bad.txt")


@given(st.binary(max_size=16))
def test_any_camera_attachment_is_a_stamp_or_none(data: bytes) -> None:
    stamp = decode_camera_stamp(data)
    assert stamp is None or (math.isfinite(stamp) and stamp > 0)


@given(st.floats(min_value=1e-3, max_value=1e12))
def test_a_camera_stamp_comes_back_as_it_went(stamp: float) -> None:
    assert decode_camera_stamp(encode_camera_stamp(stamp)) == stamp


def test_a_camera_frame_without_a_stamp_has_none() -> None:
    assert decode_camera_stamp(None) is None
    assert decode_camera_stamp(encode_camera_stamp(math.nan)) is None
