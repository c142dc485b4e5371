"""The recorder on a real graph and real files: sessions, listing, budget, disk full, reading."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any, BinaryIO

import pytest

from server.graph import Graph
from server.recorder.errors import CorruptRecording, FlightNotFound, RecorderError
from server.recorder.index import FlightIndex
from server.recorder.mcapfile import FlightFile, read_recording
from server.recorder.recorder import Recorder, RecorderConfig
from server.store import AuditLog

from .conftest import NAVDATA, Clock, navdata, utterance

LANDED, FLYING = 2, 3


def fly(graph: Graph, rec: Recorder, clock: Clock, topic: str = "/ardrone/navdata") -> None:
    """Take off, fly a few steps, land; advance the clock past the idle time."""
    for state in (6, FLYING, FLYING, 4, 8, LANDED):
        graph.publish(topic, navdata(state), type=NAVDATA)
        clock.t += 1.0
        rec.step()
    clock.t += 10.0
    rec.step()


def test_a_flight_session_is_one_complete_recording(
    rig: tuple[Graph, Recorder], clock: Clock
) -> None:
    graph, rec = rig
    graph.advertise("/console/state", "uav_console/DialogState", latch=True)
    graph.publish("/console/state", {"state": "landed", "grammars": ["main"], "drone": "uav1"})
    clock.t += 60  # long before the flight: not in the pre-roll, kept as the latest state
    rec.step()
    graph.publish("/ardrone/navdata", navdata(LANDED), type=NAVDATA)
    graph.publish("/console/utterance", utterance("take off"), type="uav_console/Utterance")
    rec.step()
    assert rec.current_id is None  # nothing flies, nobody commanded: no session
    fly(graph, rec, clock)
    assert rec.current_id is None  # landed and idle: the session ended
    flights = rec.flights()
    assert len(flights) == 1
    row = flights[0].as_json()
    assert set(row) == {"id", "started", "ended", "drones", "bytes", "messages"}
    assert row["drones"] == ["uav1"] and row["ended"] is not None
    path = rec.index.path_for(row["id"])
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert row["bytes"] == path.stat().st_size
    recording = read_recording(path)
    assert recording.complete
    topics = [ch.topic for ch, _t, _m in recording.decoded()]
    # the old latched state first, then the pre-roll (the utterance before take-off), the flight
    assert topics[0] == "/console/state"
    assert "/console/utterance" in topics[:4]
    states = [m["state"] for ch, _t, m in recording.decoded() if ch.topic == "/ardrone/navdata"]
    assert states == [LANDED, 6, FLYING, FLYING, 4, 8, LANDED]
    assert row["messages"] == len(recording.messages) == 9
    assert recording.channels[1].schema_encoding in ("ros1msg", "jsonschema")


def test_a_command_starts_the_session_and_audit_rows_carry_its_id(
    rig: tuple[Graph, Recorder], clock: Clock, tmp_path: Path
) -> None:
    graph, rec = rig
    audit = AuditLog(tmp_path / "audit.db")
    audit.recording = rec.touch
    audit.append(
        utterance="take off",
        commands=[{"action": "takeoff"}],
        action="executed",
        outcome="taking off",
    )
    rec.step()
    fid = rec.current_id
    assert fid is not None
    fly(graph, rec, clock)
    audit.recording = None
    audit.append(utterance="hello", commands=[], action="refused", outcome="?")
    entries = audit.recent()
    assert [e.recording for e in entries] == ["", fid]
    assert [f.id for f in rec.flights()] == [fid]
    audit.close()


def test_a_fleet_shares_one_recording(rig: tuple[Graph, Recorder], clock: Clock) -> None:
    graph, rec = rig
    graph.publish("/uav1/ardrone/navdata", navdata(FLYING), type=NAVDATA)
    rec.step()
    first = rec.current_id
    clock.t += 1
    graph.publish("/uav1/ardrone/navdata", navdata(LANDED), type=NAVDATA)
    graph.publish("/uav2/ardrone/navdata", navdata(FLYING), type=NAVDATA)
    rec.step()
    clock.t += 4  # uav1 long landed, uav2 still up: the same session goes on
    rec.step()
    assert rec.current_id == first
    graph.publish("/uav2/ardrone/navdata", navdata(LANDED), type=NAVDATA)
    clock.t += 10
    rec.step()
    (row,) = rec.flights()
    assert row.id == first and row.drones == ["uav1", "uav2"]


def test_unknown_types_are_recorded_as_json(rig: tuple[Graph, Recorder], clock: Clock) -> None:
    graph, rec = rig
    rec.touch()
    graph.publish("/mavros/custom", {"a": [1, 2], "b": "x"}, type="mavros_msgs/Whatever")
    graph.publish("/cmd_vel", {"linear": {"x": 0.5}}, type="geometry_msgs/Twist")
    rec.step()
    clock.t += 10
    rec.step()
    recording = read_recording(rec.index.path_for(rec.flights()[0].id))
    got = {ch.topic: (ch.message_encoding, m) for ch, _t, m in recording.decoded()}
    assert got["/mavros/custom"] == ("json", {"a": [1, 2], "b": "x"})
    assert got["/cmd_vel"][0] == "ros1"
    assert got["/cmd_vel"][1]["linear"] == {"x": 0.5, "y": 0.0, "z": 0.0}


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_disk_full_stops_recording_with_an_alert_and_flying_goes_on(
    tmp_path: Path, clock: Clock
) -> None:
    graph = Graph()
    alerts: list[dict[str, Any]] = []
    graph.subscribe("/console/reply", alerts.append, type="uav_console/Reply")

    def full_disk(path: Path) -> BinaryIO:
        path.touch(mode=0o600)  # the file exists, every byte written to it hits ENOSPC
        return open("/dev/full", "wb")  # the writer closes it

    rec = Recorder(graph, RecorderConfig(tmp_path, chunk_s=0.5), clock=clock, opener=full_disk)
    rec.start(background=False)
    graph.publish("/ardrone/navdata", navdata(FLYING), type=NAVDATA)
    rec.step()
    clock.t += 1
    rec.step()  # first flush: ENOSPC
    assert rec.last_error is not None and "disk is full" in rec.last_error
    assert [a["level"] for a in alerts] == ["alert"] and "flying goes on" in alerts[0]["text"]
    for _ in range(5):  # the vehicle keeps publishing, the recorder keeps out of the way
        graph.publish("/ardrone/navdata", navdata(FLYING), type=NAVDATA)
        clock.t += 1
        rec.step()
    assert len(alerts) == 1
    rec.stop()


def _old_flight(index: FlightIndex, fid: str, size: int) -> None:
    f = FlightFile(index.directory / f"{fid}.mcap", fid, 1)
    f.write("/pad", "std_msgs/String", 1, {"data": os.urandom(size).hex()})
    f.finish(2, ["uav1"])


def test_disk_budget_deletes_the_oldest_never_the_current(tmp_path: Path, clock: Clock) -> None:
    graph = Graph()
    alerts: list[dict[str, Any]] = []
    graph.subscribe("/console/reply", alerts.append, type="uav_console/Reply")
    clock.t = 1_780_272_000.0  # 2026-06-01, after the old flights
    index = FlightIndex(tmp_path, 0)
    index.ensure_dir()
    for fid in ("20260101T000000Z", "20260102T000000Z", "20260103T000000Z"):
        _old_flight(index, fid, 12_000)
    sizes = [p.stat().st_size for p in index.files()]
    budget = sizes[1] + sizes[2] + 5_000  # room for two old ones and a short flight
    rec = Recorder(graph, RecorderConfig(tmp_path, budget_bytes=budget, chunk_s=0.5), clock=clock)
    rec.start(background=False)
    graph.publish("/ardrone/navdata", navdata(FLYING), type=NAVDATA)
    rec.step()
    current = rec.current_id
    ids = [f.id for f in rec.flights()]
    assert ids == ["20260102T000000Z", "20260103T000000Z", current]  # oldest went first
    big = {"data": os.urandom(40_000).hex()}
    graph.publish("/pad", big, type="std_msgs/String")
    clock.t += 1
    rec.step()
    # the others were deleted, then the current one alone was over: it stops, with an alert
    assert [f.id for f in rec.index.listing()] == [current]
    assert rec.last_error is not None and "disk budget" in rec.last_error
    assert alerts and alerts[-1]["level"] == "alert"
    # stopped at the budget, the file is finished (a summary, listed without a scan)
    stopped = read_recording(rec.index.path_for(current))
    assert stopped.complete and stopped.topics.get("/pad") == "std_msgs/String"
    rec.stop()


def test_listing_delete_and_ids(tmp_path: Path) -> None:
    index = FlightIndex(tmp_path, 10**9)
    index.ensure_dir()
    _old_flight(index, "20260102T000000Z", 10)
    _old_flight(index, "20260101T000000Z", 10)
    (tmp_path / "notes.txt").write_text("not a flight")
    assert [f.id for f in index.listing()] == ["20260101T000000Z", "20260102T000000Z"]
    with pytest.raises(FlightNotFound):
        index.path_for("../audit")
    with pytest.raises(FlightNotFound):
        index.delete("20990101T000000Z", None)
    with pytest.raises(RecorderError, match="being recorded"):
        index.delete("20260101T000000Z", "20260101T000000Z")
    index.delete("20260101T000000Z", None)
    assert [f.id for f in index.listing()] == ["20260102T000000Z"]
    assert index.new_id(1_767_225_600.0) == "20260101T000000Z"
    (tmp_path / "20260101T000000Z.mcap").touch()
    assert index.new_id(1_767_225_600.0) == "20260101T000000Z-2"


def _recording(tmp_path: Path, n: int = 50) -> Path:
    path = tmp_path / "20260101T000000Z.mcap"
    f = FlightFile(path, "x", 1, chunk_size=300)
    for i in range(n):
        f.write("/ardrone/navdata", NAVDATA, 10 + i, navdata(FLYING, battery=float(i)))
    f.finish(100, ["uav1"])
    return path


def test_truncated_and_corrupt_files_name_the_offset(tmp_path: Path) -> None:
    path = _recording(tmp_path)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptRecording, match=r"truncated.*at byte offset \d+") as err:
        read_recording(cut)
    partial = read_recording(cut, strict=False)
    assert 0 < len(partial.messages) < 50 and partial.stopped is not None
    assert partial.good_until == err.value.offset
    batteries = [m["batteryPercent"] for _c, _t, m in partial.decoded()]
    assert batteries == [float(i) for i in range(len(batteries))]  # a prefix, in order

    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"PK\x03\x04 not mcap")
    with pytest.raises(CorruptRecording, match=r"bad magic.*offset 0"):
        read_recording(bad)

    flipped = bytearray(data)
    at = data.index(b"\x06", 100)  # inside the first chunk's compressed body, roughly
    flipped[at + 40] ^= 0xFF
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(bytes(flipped))
    with pytest.raises(CorruptRecording, match=r"byte offset \d+"):
        read_recording(corrupt)


def test_a_crash_cut_file_is_repaired_at_start(tmp_path: Path, clock: Clock) -> None:
    flights = tmp_path / "flights"
    flights.mkdir()
    path = _recording(flights)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    survivors = len(read_recording(path, strict=False).messages)
    rec = Recorder(Graph(), RecorderConfig(flights), clock=clock)
    rec.start(background=False)
    repaired = read_recording(path)
    assert repaired.complete and len(repaired.messages) == survivors
    assert "cut short at byte" in repaired.metadata["flight_end"]["repaired"]
    (row,) = rec.flights()
    assert row.messages == survivors and row.ended is not None
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    rec.stop()
    assert json.loads(json.dumps(row.as_json()))["id"] == path.stem


def test_state_from_long_before_the_flight_does_not_stretch_its_timeline(tmp_path: Path) -> None:
    """A dialog state latched at start-up, 12 minutes before the take-off, is in the recording
    (the state a replay starts from) but logged at the recording's start: the recording spans
    the flight (pre-roll included), not the 12 minutes before it."""
    graph, clock = Graph(), Clock(1_780_000_000.0)
    config = RecorderConfig(tmp_path / "flights", idle_s=2.0, preroll_s=10.0)
    rec = Recorder(graph, config, clock=clock, stamp_ns=lambda: int(clock.t * 1e9))
    rec.start(background=False)
    graph.advertise("/console/state", "uav_console/DialogState", latch=True)
    state = {
        "header": {"stamp": {"sec": 1_780_000_000, "nanosec": 0}, "frame_id": ""},
        "state": "landed",
        "grammars": ["main"],
        "drone": "uav1",
    }
    graph.publish("/console/state", state)
    rec.step()
    clock.t += 720.0
    for i in range(350):  # 35 s: take off, fly, land
        graph.publish("/ardrone/navdata", navdata(LANDED if i >= 340 else FLYING), type=NAVDATA)
        clock.t += 0.1
        rec.step()
    clock.t += 5.0
    rec.step()
    rec.stop()
    (row,) = rec.flights()
    recording = read_recording(rec.index.path_for(row.id))
    times = [t for _ch, t, _m in recording.decoded()]
    assert (max(times) - min(times)) / 1e9 < 35.0 + 1.0
    first_topic, first_msg = next((ch.topic, m) for ch, _t, m in recording.decoded())
    assert first_topic == "/console/state"
    assert first_msg["header"]["stamp"]["sec"] == 1_780_000_000  # the message as published
    assert recording.metadata["flight"]["preroll_s"] == "10.0"
