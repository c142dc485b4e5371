"""World files: the named worlds load and are sane; bad files raise WorldError naming the field."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drone.sim.world import (
    ARUCO_MAX_ID,
    WORLDS_DIR,
    World,
    WorldError,
    load_world,
    parse_world,
)


@pytest.fixture(scope="module")
def indoor() -> World:
    return load_world("indoor")


@pytest.fixture(scope="module")
def outdoor() -> World:
    return load_world("outdoor")


def _raw(name: str) -> dict[str, Any]:
    return yaml.safe_load((WORLDS_DIR / f"{name}.yaml").read_text())


# -------------------------------------------------------------------------- the indoor room


def test_indoor_room_size_and_frame(indoor: World) -> None:
    b = indoor.bounds
    assert (b.x_min, b.y_min, b.z_min) == (0.0, 0.0, 0.0)  # origin at a floor corner
    length, width, height = b.size
    assert 7.0 <= length <= 9.0 and 5.0 <= width <= 7.0 and 2.5 <= height <= 3.5
    assert indoor.indoor and indoor.gps_origin is None


def test_indoor_markers_on_walls_facing_in(indoor: World) -> None:
    assert len(indoor.markers) >= 12
    ids = indoor.marker_ids()
    assert len(set(ids)) == len(ids) and all(0 <= i <= ARUCO_MAX_ID for i in ids)
    b = indoor.bounds
    for m in indoor.markers:
        x, y, z = m.position
        assert 1.2 <= z <= 1.6, m
        assert m.size_m == pytest.approx(0.20)
        wall_dist = min(x - b.x_min, b.x_max - x, y - b.y_min, b.y_max - y)
        assert wall_dist < 0.05, f"marker {m.id} is not on a wall"
        # facing into the room: a point 1 m along the normal is inside, 1 m behind is not
        front = np.asarray(m.position) + m.normal
        back = np.asarray(m.position) - m.normal
        assert b.contains(*front) and not b.contains(*back), m


def test_marker_corners_follow_aruco_order(indoor: World) -> None:
    for m in indoor.markers:
        c = m.corners()
        tl, tr, br, bl = c
        assert tl[2] > bl[2] and tr[2] > br[2]  # top above bottom
        assert np.linalg.norm(tr - tl) == pytest.approx(m.size_m)
        # seen from the front (looking along -normal) TL is on the viewer's left
        view = -m.normal
        left = np.array([-view[1], view[0], 0.0])  # viewer's left, REP 103 (CCW)
        assert (tl - tr) @ left > 0
        # the marker's z axis is the outward normal
        assert np.allclose(m.rotation()[:, 2], m.normal)
        assert np.allclose(c.mean(axis=0), m.position)


def test_indoor_objects_for_the_captioner(indoor: World) -> None:
    kinds = {o.kind for o in indoor.objects}
    assert {"chair", "table", "door", "window", "person", "plant"} <= kinds
    chairs = [o for o in indoor.objects if o.kind == "chair"]
    assert len({o.colour for o in chairs}) == len(chairs)  # told apart by colour
    for o in indoor.objects:
        assert indoor.bounds.contains(*o.position, margin=-0.01), o


def test_marker_lookup_and_standoff(indoor: World) -> None:
    m = indoor.marker(3)
    assert m.id == 3
    with pytest.raises(KeyError, match="no marker 42"):
        indoor.marker(42)
    s = m.standoff(1.0)
    assert math.dist((s.x, s.y, s.z), m.position) == pytest.approx(1.0)
    # facing the marker: heading points from the stand-off towards the marker
    assert math.cos(s.yaw_rad - math.atan2(m.position[1] - s.y, m.position[0] - s.x)) > 0.999


def test_start_pose_and_stations(indoor: World) -> None:
    assert indoor.bounds.contains(indoor.start.x, indoor.start.y, indoor.start.z)
    assert indoor.station("home1").position[:2] == (indoor.start.x, indoor.start.y)
    with pytest.raises(KeyError):
        indoor.station("nope")


# -------------------------------------------------------------------------- the outdoor field


def test_outdoor_gps_origin_and_square(outdoor: World) -> None:
    g = outdoor.gps_origin
    assert g is not None
    assert (g.lat_deg, g.lon_deg) == (36.367164, 127.363472)
    assert 50 <= g.alt_m <= 70
    assert not outdoor.indoor and len(outdoor.stations) >= 2
    pts = [np.asarray(w.position[:2]) for w in outdoor.waypoints]
    assert len(pts) == 4
    sides = [np.linalg.norm(pts[i] - pts[(i + 1) % 4]) for i in range(4)]
    assert all(20 <= s <= 40 for s in sides) and max(sides) - min(sides) < 1e-9
    diag = np.linalg.norm(pts[0] - pts[2])
    assert diag == pytest.approx(sides[0] * math.sqrt(2))
    for w in outdoor.waypoints:
        assert outdoor.bounds.contains(*w.position)
        assert w.geo is not None and abs(w.geo.lat_deg - g.lat_deg) < 0.001


def test_lat_lon_waypoints_convert_to_enu(tmp_path: Path) -> None:
    raw = _raw("outdoor")
    raw["waypoints"] = [{"id": "n100", "lat": 36.367164 + 100 / 111_000, "lon": 127.363472}]
    raw["bounds"]["y_max"] = 200.0
    p = tmp_path / "w.yaml"
    p.write_text(yaml.safe_dump(raw))
    w = load_world(str(p))
    x, y, _ = w.waypoints[0].position
    assert abs(x) < 0.5 and y == pytest.approx(100, abs=1.0)


# -------------------------------------------------------------------------- JSON for the API


def test_to_json_has_markers_stations_bounds_origin(indoor: World, outdoor: World) -> None:
    d = json.loads(indoor.to_json())
    assert {m["id"] for m in d["markers"]} == set(indoor.marker_ids())
    m0 = next(m for m in d["markers"] if m["id"] == 0)
    assert set(m0) >= {"id", "position", "yaw_deg", "yaw_rad", "size_m"}
    assert m0["position"]["z"] == indoor.marker(0).position[2]
    assert d["bounds"]["x_max"] == indoor.bounds.x_max
    assert d["stations"][0]["id"] == "home1"
    assert d["gps_origin"] is None
    o = json.loads(outdoor.to_json())
    assert o["gps_origin"] == {"lat": 36.367164, "lon": 127.363472, "alt": 60.0}
    assert len(o["waypoints"]) == 4 and "lat" in o["waypoints"][0]


def test_load_by_path_yaml_and_json(tmp_path: Path) -> None:
    raw = _raw("indoor")
    (tmp_path / "room.json").write_text(json.dumps(raw))
    (tmp_path / "room.yaml").write_text(yaml.safe_dump(raw))
    a = load_world(str(tmp_path / "room.json"))
    b = load_world(str(tmp_path / "room.yaml"))
    assert a.markers == b.markers == load_world("indoor").markers


def test_with_objects_replaces_only_objects(indoor: World) -> None:
    w2 = indoor.with_objects(indoor.objects[:2])
    assert len(w2.objects) == 2 and w2.markers == indoor.markers


# -------------------------------------------------------------------------- bad input


def _set(d: dict[str, Any], path: str, value: Any) -> None:
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if k.isdigit() else d[k]  # type: ignore[index]
    last = keys[-1]
    if value is _DEL:
        del d[last]
    elif last.isdigit():
        d[int(last)] = value  # type: ignore[index]
    else:
        d[last] = value


_DEL = object()

BAD = [
    ("name", _DEL, "missing field 'name'"),
    ("kind", "underwater", "kind"),
    ("bounds", _DEL, "missing field 'bounds'"),
    ("bounds.x_max", -1.0, "bounds.x_max"),
    ("bounds.z_min", "low", "bounds.z_min"),
    ("bounds.y_max", float("nan"), "bounds.y_max"),
    ("markers.0.id", 50, "markers[0].id"),
    ("markers.0.id", True, "markers[0].id"),
    ("markers.1.id", 0, "duplicate marker id 0"),
    ("markers.2.position", [1, 2], "markers[2].position"),
    ("markers.2.position", [100.0, 1.0, 1.0], "markers[2].position"),
    ("markers.3.yaw_deg", _DEL, "markers[3]: missing field 'yaw_deg'"),
    ("markers.3.size_m", -0.2, "markers[3].size_m"),
    ("markers.4.yaw_deg", 0, "markers[4].yaw_deg: the marker faces out of the room"),
    ("marker_size_m", _DEL, "markers[0]: missing field 'size_m'"),
    ("markers", {"id": 1}, "markers"),
    ("objects.0.kind", "dragon", "objects[0].kind"),
    ("objects.1.colour", "octarine", "objects[1].colour"),
    ("objects.1.bgr", [0, 0, 300], "objects[1].bgr"),
    ("objects.2.size", [1.0, 0.0, 1.0], "objects[2].size[1]"),
    ("objects.2.position", None, "objects[2].position"),
    ("objects.3.id", "door1", "duplicate object id 'door1'"),
    ("stations.0.position", [-5.0, 0.0, 0.0], "stations[0].position"),
    ("start.position", [50.0, 1.0, 0.0], "start.position"),
    ("surfaces.floor", [1, 2], "surfaces.floor"),
    ("gps_origin", {"lat": 95.0, "lon": 0.0}, "gps_origin.lat"),
    ("waypoints", [{"id": "a", "lat": 1.0, "lon": 2.0}], "need a gps_origin"),
    ("waypoints", [{"id": "a"}], "waypoints[0]: missing field 'position'"),
]


@pytest.mark.parametrize(("path", "value", "field"), BAD, ids=[b[0] + ":" + b[2] for b in BAD])
def test_bad_world_names_file_and_field(tmp_path: Path, path: str, value: Any, field: str) -> None:
    raw = copy.deepcopy(_raw("indoor"))
    _set(raw, path, value)
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(raw))
    with pytest.raises(WorldError) as e:
        load_world(str(f))
    assert str(f) in str(e.value)
    assert field in str(e.value)


def test_missing_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(WorldError, match="no such world file"):
        load_world("atlantis")
    bad = tmp_path / "broken.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(WorldError, match="not valid yaml"):
        load_world(str(bad))
    bad.write_text("- just\n- a list\n")
    with pytest.raises(WorldError, match="document: expected a mapping"):
        load_world(str(bad))
    js = tmp_path / "w.json"
    js.write_text("{nope")
    with pytest.raises(WorldError, match="not valid json"):
        load_world(str(js))
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(WorldError):
        load_world(str(binary))


_json = st.recursive(
    st.none() | st.booleans() | st.integers(-100, 100) | st.floats() | st.text(max_size=8),
    lambda kids: (
        st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=8), kids, max_size=4)
    ),
    max_leaves=20,
)
_KEYS = [
    "name",
    "kind",
    "bounds",
    "markers",
    "objects",
    "stations",
    "gps_origin",
    "waypoints",
    "start",
    "surfaces",
    "marker_size_m",
]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.sampled_from(_KEYS), _json, max_size=8))
def test_arbitrary_documents_parse_or_raise_world_error(doc: dict[str, Any]) -> None:
    try:
        w = parse_world(doc, "fuzz")
    except WorldError as e:
        assert str(e).startswith("fuzz: ")
    else:
        assert isinstance(w, World)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 11), st.sampled_from(["markers", "objects", "bounds", "start"]), _json)
def test_corrupting_one_field_parses_or_raises(i: int, key: str, junk: Any) -> None:
    raw = copy.deepcopy(_raw("indoor"))
    if key in ("markers", "objects"):
        raw[key][i % len(raw[key])] = junk
    else:
        raw[key] = junk
    try:
        parse_world(raw, "x.yaml")
    except WorldError as e:
        assert str(e).startswith("x.yaml: ")
