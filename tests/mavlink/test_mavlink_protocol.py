"""The console's MAVLink protocol against the simulated PX4 autopilot, in lockstep (no sockets):
commands with ACK, retries without double execution, denials explained, silent and rejecting
vehicles, a second system id, garbage on the link, link loss and the autopilot's failsafe,
offboard jog released to zero, the mission protocol flying a patrol."""

from __future__ import annotations

import math
from typing import Any

import pytest

from drone.mavlink.codec import Codec, mav
from drone.mavlink.gcs.events import (
    CommandResult,
    LinkLost,
    LinkRestored,
    MissionItemReached,
    MissionResult,
    OtherVehicle,
    StatusText,
)
from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.link import MavlinkMemoryLink
from drone.mavlink.sim.autopilot import SimAutopilot
from drone.sim.world import load_world

DT = 0.02


@pytest.fixture(scope="module")
def world() -> Any:
    return load_world("outdoor")


class Rig:
    def __init__(self, world: Any, **kw: Any) -> None:
        tamper = kw.pop("tamper", None)
        self.ap = SimAutopilot(world, **kw)
        self.p = GcsProtocol()
        self.link = MavlinkMemoryLink(self.p, self.ap, tamper=tamper)
        self.t = 0.0
        self.events: list[Any] = []

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / DT)):
            self.events += self.link.step(self.t, DT)
            self.t += DT

    def until(self, pred: Any, timeout: float) -> bool:
        end = self.t + timeout
        while self.t < end:
            self.run(DT)
            if pred():
                return True
        return False

    def results(self, name: str | None = None) -> list[CommandResult]:
        return [
            e
            for e in self.events
            if isinstance(e, CommandResult) and (name is None or e.command == name)
        ]

    def connect(self) -> None:
        assert self.until(
            lambda: (
                self.p.connected
                and self.p.telemetry.home is not None
                and self.p.pending_commands() == 0
            ),
            5.0,
        )


def test_discovery_streams_and_health(world: Any) -> None:
    r = Rig(world)
    r.connect()
    r.run(1.0)
    t = r.p.telemetry
    assert (t.system_id, t.autopilot, t.mode) == (1, "PX4", "AUTO.LOITER")
    assert t.sensors_ok and t.gps_fix == 3 and t.landed_state == "ON_GROUND"
    assert math.isclose(t.lat_deg, 36.367164, abs_tol=1e-6)
    ok = r.results("SET_MESSAGE_INTERVAL")
    assert len(ok) == 8 and all(x.ok for x in ok)
    assert r.ap.links["memory"].rates_hz["GLOBAL_POSITION_INT"] == pytest.approx(10.0)
    assert r.p.params["NAV_DLL_ACT"] == 2.0  # read for the link-loss alert


def test_arm_takeoff_land_disarm(world: Any) -> None:
    r = Rig(world)
    r.connect()
    r.p.arm_and_takeoff(3.0)
    assert r.until(lambda: r.p.telemetry.rel_alt_m > 2.9, 10.0)
    assert [e.command for e in r.results() if e.command != "SET_MESSAGE_INTERVAL"][-2:] == [
        "COMPONENT_ARM_DISARM",
        "NAV_TAKEOFF",
    ]
    r.run(1.0)
    assert r.p.telemetry.armed and r.p.telemetry.landed_state == "IN_AIR"
    r.p.intent("land")
    assert r.until(lambda: not r.p.telemetry.armed, 20.0)  # lands, then auto-disarms (2 s)
    assert r.ap.physics.body.z == pytest.approx(0.0)


def test_take_off_again_the_moment_the_px4_auto_disarms(world: Any) -> None:
    """The console's "armed" is a heartbeat old: a take-off sent just after the PX4 disarmed
    on landing still arms first (a bare NAV_TAKEOFF was denied, "Takeoff denied: disarmed")."""
    r = Rig(world)
    r.connect()
    r.p.arm_and_takeoff(3.0)
    assert r.until(lambda: r.p.telemetry.rel_alt_m > 2.9, 10.0)
    r.p.intent("land")
    assert r.until(lambda: not r.ap.armed, 20.0)
    assert r.p.telemetry.armed  # not heard yet
    r.p.arm_and_takeoff(3.0)
    assert r.until(lambda: r.p.telemetry.rel_alt_m > 2.9, 10.0)
    assert all(e.ok for e in r.results("NAV_TAKEOFF"))


def test_denial_carries_the_vehicles_reason(world: Any) -> None:
    r = Rig(world)
    r.connect()
    r.p.arm_and_takeoff(3.0)
    assert r.until(lambda: r.p.telemetry.rel_alt_m > 2.9, 10.0)
    r.p.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)  # disarm in the air: PX4 denies
    r.run(0.5)
    res = r.results("COMPONENT_ARM_DISARM")[-1]
    assert res.result == "DENIED" and res.reason == "Disarming denied: not landed"
    assert r.p.telemetry.armed


def test_lost_acks_are_retried_but_never_executed_twice(world: Any) -> None:
    state = {"drop": True}

    def drop_acks(data: bytes) -> bytes:
        if not state["drop"]:
            return data
        c = Codec(1, 1)
        out = bytearray()
        for m in c.feed(data):
            if m.get_type() != "COMMAND_ACK":
                out += m.get_msgbuf()
        return bytes(out)

    r = Rig(world, tamper=drop_acks)
    r.run(0.5)
    state["drop"] = False
    r.connect()
    sent0 = r.p.commands_sent
    state["drop"] = True
    r.p.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    r.run(2.5)  # two ACKs lost → two retransmissions (confirmation 1, 2)
    state["drop"] = False
    r.run(1.5)
    # sent at 0 s; ACKs of the sends at 0, 1 and 2 s lost; the fourth (3 s) is answered
    assert r.p.commands_sent - sent0 == 4
    assert r.ap.commands_executed.count(mav.MAV_CMD_COMPONENT_ARM_DISARM) == 1
    assert r.results("COMPONENT_ARM_DISARM")[-1].ok


def test_identical_command_queued_once(world: Any) -> None:
    r = Rig(world)
    r.connect()
    a = r.p.intent("hold")
    b = r.p.intent("hold")
    c = r.p.intent("hold")
    assert a == b == c  # one in flight; the same request again is the same command
    r.run(0.5)
    assert len(r.results("DO_SET_MODE")) == 1


def test_silent_vehicle_gives_no_answer_after_retries(world: Any) -> None:
    r = Rig(world, silent=True)
    r.p.request_streams = False  # it would not answer those either
    r.connect()
    before = r.p.commands_sent
    r.p.arm_and_takeoff(2.5)
    r.run(5.0)
    res = [
        e for e in r.events if isinstance(e, CommandResult) and e.command != "SET_MESSAGE_INTERVAL"
    ]
    assert [(e.command, e.result) for e in res] == [
        ("COMPONENT_ARM_DISARM", "NO_ANSWER"),
        ("NAV_TAKEOFF", "NOT_SENT"),
    ]
    assert r.p.commands_sent - before == 1 + r.p.retries  # then it stops: nothing more
    r.run(3.0)
    assert r.p.commands_sent - before == 1 + r.p.retries
    assert not r.p.telemetry.armed


def test_rejecting_vehicle(world: Any) -> None:
    r = Rig(world, refuse_all=True)
    r.run(2.0)
    r.p.arm_and_takeoff(2.5)
    r.run(1.0)
    arm = r.results("COMPONENT_ARM_DISARM")[-1]
    assert arm.result == "DENIED" and arm.reason == "Command denied: vehicle locked"
    assert r.results("NAV_TAKEOFF")[-1].result == "NOT_SENT"
    assert r.ap.commands_executed == []


def test_second_system_id_is_ignored(world: Any) -> None:
    r = Rig(world)
    r.connect()
    other = Codec(42, 1)
    intruder = other.encode(other.mav.heartbeat_encode(2, 12, 0x80, 0, 4))
    gpi = other.encode(other.mav.global_position_int_encode(0, 0, 0, 999_000, 0, 0, 0, 0, 0))
    r.p.receive(intruder + gpi + intruder, r.t)
    r.run(0.5)
    assert [e for e in r.events if isinstance(e, OtherVehicle)] == [OtherVehicle(42)]
    assert r.p.telemetry.system_id == 1 and not r.p.telemetry.armed
    assert r.p.telemetry.alt_amsl_m == pytest.approx(60.0, abs=0.1)


def test_garbage_bad_crc_and_mavlink1_on_the_downlink(world: Any) -> None:
    def mangle(data: bytes) -> bytes:
        bad = bytearray(data)
        if len(bad) > 30:
            bad[12] ^= 0x5A  # corrupt the first frame: its CRC fails
        return b"\xfd\x00garbage" + bytes(bad)[:60] + bytes(range(256))[:40]

    r = Rig(world, tamper=mangle)
    r.run(1.0)
    rej = r.p.codec.rejected
    assert rej["garbage"] + rej["bad_crc"] > 0
    assert not r.p.connected  # nothing valid arrived: no vehicle invented


def test_link_loss_alert_then_autopilot_returns_home(world: Any) -> None:
    r = Rig(world)
    r.connect()
    r.p.arm_and_takeoff(3.0)
    assert r.until(lambda: r.p.telemetry.rel_alt_m > 2.9, 10.0)
    r.p.goto(*world.waypoints[2].geo.__dict__.values())
    r.run(3.0)
    r.link.inject_fault("link_loss", duration_s=14.0)
    r.run(2.0)
    lost = [e for e in r.events if isinstance(e, LinkLost)]
    assert len(lost) == 1
    assert lost[0].failsafe == "PX4's data-link-loss failsafe will return to launch after 10 s"
    r.run(13.0)
    assert r.ap.mode == "AUTO.RTL"  # PX4's own failsafe acted (NAV_DLL_ACT 2)
    assert any(isinstance(e, LinkRestored) for e in r.events)
    # said while nobody could hear it, as on a real link
    assert "Failsafe: no connection to GCS, returning" in r.ap.statustexts
    assert r.until(lambda: not r.p.telemetry.armed, 60.0)
    b = r.ap.physics.body
    assert math.hypot(b.x - r.ap.home[0], b.y - r.ap.home[1]) < 0.6


def test_velocity_jog_streams_then_zero_on_release(world: Any) -> None:
    r = Rig(world)
    r.connect()
    r.p.arm_and_takeoff(3.0)
    assert r.until(lambda: r.p.telemetry.rel_alt_m > 2.9, 10.0)
    r.p.set_velocity(2.0, 0.0, 0.0, 0.0)
    r.p.intent("offboard")
    r.run(2.0)
    assert r.ap.mode == "OFFBOARD" and r.ap.physics.body.vy > 1.5  # north = map +y
    r.p.stop_setpoints()
    r.run(0.3)
    assert r.p.streaming is None and r.ap._vel_sp == (0.0, 0.0, 0.0)
    r.run(3.0)  # no setpoints: PX4's offboard-loss failsafe holds
    assert r.ap.mode == "AUTO.LOITER"
    assert math.hypot(r.ap.physics.body.vx, r.ap.physics.body.vy) < 0.2


def test_mission_upload_and_patrol(world: Any) -> None:
    r = Rig(world)
    r.connect()
    wps = [(w.geo.lat_deg, w.geo.lon_deg, 5.0) for w in world.waypoints]
    r.p.upload_mission(wps, takeoff_alt_m=5.0, rtl=True)
    r.run(1.0)
    up = [e for e in r.events if isinstance(e, MissionResult)]
    assert up == [MissionResult(True, 6, "ACCEPTED")]
    r.p.command(
        mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, then=[(mav.MAV_CMD_MISSION_START, (0.0, 0.0))]
    )
    assert r.until(lambda: not r.p.telemetry.armed and r.t > 10, 200.0)
    reached = [e.seq for e in r.events if isinstance(e, MissionItemReached)]
    assert reached == [0, 1, 2, 3, 4]
    b = r.ap.physics.body
    assert math.hypot(b.x - r.ap.home[0], b.y - r.ap.home[1]) < 0.6


def test_mission_outside_the_world_is_refused(world: Any) -> None:
    r = Rig(world)
    r.connect()
    r.p.upload_mission([(36.5, 127.5, 5.0)])
    r.run(1.0)
    res = [e for e in r.events if isinstance(e, MissionResult)]
    assert len(res) == 1 and not res[0].ok
    assert res[0].detail == "ERROR: Mission item 0 outside"


class FakeVehicle:
    """A hand-driven vehicle end (a Codec), for what the simulator does not do by itself."""

    def __init__(self, autopilot: int, system_id: int = 1) -> None:
        self.codec = Codec(system_id, 1)
        self.autopilot = autopilot

    def heartbeat(self) -> bytes:
        return self.codec.encode(
            self.codec.mav.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, self.autopilot, 0, 0, 3)
        )

    def ack(self, command: int, result: int, progress: int = 0) -> bytes:
        return self.codec.encode(self.codec.mav.command_ack_encode(command, result, progress))


def test_command_progress_keeps_it_alive_without_retries() -> None:
    v = FakeVehicle(mav.MAV_AUTOPILOT_PX4)
    p = GcsProtocol(request_streams=False)
    p.receive(v.heartbeat(), 0.0)
    tok = p.command(mav.MAV_CMD_DO_SET_MODE, 1, 4, 3, now=0.0)
    sent = p.commands_sent
    p.receive(v.ack(mav.MAV_CMD_DO_SET_MODE, mav.MAV_RESULT_IN_PROGRESS, 40), 0.2)
    for t in (0.5, 1.0, 1.5, 2.0):  # past the 1 s timeout: progressing, so no retransmission
        p.receive(v.heartbeat(), t)
        p.tick(t)
    p.receive(v.ack(mav.MAV_CMD_DO_SET_MODE, mav.MAV_RESULT_IN_PROGRESS, 80), 2.2)
    p.receive(v.ack(mav.MAV_CMD_DO_SET_MODE, mav.MAV_RESULT_ACCEPTED), 2.4)
    events = p.events()
    progress = [
        e.progress_pct
        for e in events
        if getattr(e, "token", None) == tok and hasattr(e, "progress_pct")
    ]
    assert progress == [40, 80]
    assert [e.result for e in events if isinstance(e, CommandResult)] == ["ACCEPTED"]
    assert p.commands_sent == sent
    # a late duplicate ACK after the end changes nothing
    p.receive(v.ack(mav.MAV_CMD_DO_SET_MODE, mav.MAV_RESULT_DENIED), 2.5)
    assert not [e for e in p.events() if isinstance(e, CommandResult)]


def test_arducopter_modes_on_the_wire() -> None:
    v = FakeVehicle(mav.MAV_AUTOPILOT_ARDUPILOTMEGA)
    p = GcsProtocol(request_streams=False)
    p.receive(v.heartbeat(), 0.0)
    p.data_to_send()
    p.intent("hold")
    p.intent("offboard")  # queued behind the first DO_SET_MODE
    sent = [m for m in v.codec.feed(p.data_to_send()) if m.get_type() == "COMMAND_LONG"]
    assert [(m.command, m.param1, m.param2) for m in sent] == [(176, 1.0, 5.0)]  # LOITER
    p.receive(v.ack(176, mav.MAV_RESULT_ACCEPTED), 0.1)
    sent = [m for m in v.codec.feed(p.data_to_send()) if m.get_type() == "COMMAND_LONG"]
    assert [(m.command, m.param2) for m in sent] == [(176, 4.0)]  # GUIDED
    assert p.failsafe_text() == "ArduPilot's GCS failsafe (FS_GCS_ENABLE) acts after FS_GCS_TIMEOUT"


def test_arducopter_takeoff_goes_through_guided_then_arms() -> None:
    v = FakeVehicle(mav.MAV_AUTOPILOT_ARDUPILOTMEGA)
    p = GcsProtocol(request_streams=False)
    p.receive(v.heartbeat(), 0.0)
    p.data_to_send()
    p.arm_and_takeoff(5.0)
    wire: list[tuple[int, float, float]] = []
    for t in (0.1, 0.2, 0.3):
        cmds = [m for m in v.codec.feed(p.data_to_send()) if m.get_type() == "COMMAND_LONG"]
        assert len(cmds) == 1  # one at a time: each waits for the one before to be accepted
        wire.append((cmds[0].command, cmds[0].param1, cmds[0].param7))
        p.receive(v.ack(cmds[0].command, mav.MAV_RESULT_ACCEPTED), t)
    assert [w[0] for w in wire] == [176, 400, 22]  # GUIDED, arm, take-off
    assert wire[0][1] == 1.0 and wire[2][2] == 5.0  # custom mode flag; altitude above home


def test_long_statustext_in_chunks_is_put_back_together() -> None:
    v = FakeVehicle(mav.MAV_AUTOPILOT_PX4)
    p = GcsProtocol(request_streams=False)
    p.receive(v.heartbeat(), 0.0)
    text = "Preflight Fail: Accel Sensor 0 missing; check the wiring of the IMU before flight"
    chunks = [text[i : i + 50] for i in range(0, len(text), 50)]
    m = v.codec.mav
    data = b"".join(
        v.codec.encode(m.statustext_encode(3, c.encode(), 7, i)) for i, c in enumerate(chunks)
    )
    data += v.codec.encode(m.statustext_encode(6, b"short one"))
    p.receive(data, 0.1)
    texts = [e.text for e in p.events() if isinstance(e, StatusText)]
    assert texts == [text, "short one"]
