"""Forged navdata against the driver's protocol and the plausibility checks, sans-I/O.

The AR.Drone's navdata has no authentication. Found by the campaigns: one forged packet with
battery 3 % made the console land a drone at 85 %; a far-ahead sequence made the driver drop
every real packet after it; and sequence 1 ("a restart") with battery 3 % at 30 Hz was followed
as the drone's stream while the drone's own packets were held back as a jump, so the forged
3 % was believed and the drone landed. Now the driver follows one numbering while it is alive,
changes only on the drone's own evidence, believes the battery only where the drain-and-sag
model allows, and says when it doubts the stream.
"""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from test_driver_protocol import handshake

from drone.ardrone.navdata import CtrlState, Demo, DroneState, Navdata, encode_navdata
from drone.ardrone.plausibility import (
    BatteryEnvelope,
    NavdataPlausibility,
    PlausibilityConfig,
    SequenceGuard,
    load_of,
)
from drone.ardrone.protocol import (
    DriverProtocol,
    LinkLost,
    LinkRestored,
    LinkState,
    NavdataDoubt,
    NavdataReceived,
    NavdataRejected,
    NavdataTrusted,
)

FLYING = CtrlState.FLYING << 16
HOVERING = CtrlState.HOVERING << 16
PERIOD = 1.0 / 15  # demo navdata (Developer Guide §7.1.2)
CFG = PlausibilityConfig()


def packet(
    seq: int,
    battery: int = 100,
    state: DroneState = DroneState.NAVDATA_DEMO | DroneState.FLY,
    ctrl: int = FLYING,
    vz_mm_s: float = 0.0,
) -> Navdata:
    demo = Demo(ctrl_state=ctrl, battery_pct=battery, vz_mm_s=vz_mm_s)
    return Navdata(state=state, sequence=seq, demo=demo)


def pkt(seq: int, battery: int = 100, **kw: object) -> bytes:
    return encode_navdata(packet(seq, battery, **kw))  # type: ignore[arg-type]


def battery(proto: DriverProtocol) -> int:
    assert proto.latest is not None and proto.latest.demo is not None
    return proto.latest.demo.battery_pct


def streaming(seq0: int = 5000) -> tuple[DriverProtocol, float, int]:
    """A protocol following a drone whose sequence is at ``seq0`` (up for minutes: the console
    met it after a link loss, when any numbering is followed)."""
    proto = DriverProtocol()
    t = handshake(proto) + 0.6
    assert [type(e) for e in proto.poll_events(t)] == [LinkLost]
    t += PERIOD
    proto.receive_navdata(pkt(seq0), t)
    assert proto.state is LinkState.READY and proto.latest is not None
    assert proto.latest.sequence == seq0
    return proto, t, seq0


# ---------------------------------------------------------------------------- driver, sequence


def test_a_forged_packet_neither_lands_the_drone_nor_silences_it() -> None:
    proto = DriverProtocol()
    t = handshake(proto)  # real stream at sequence 5
    seq = 5
    for i in range(10):
        seq += 1
        proto.receive_navdata(pkt(seq), t + 0.07 * i)
    t += 0.7
    # the attacker's packet: battery 3 %, sequence far ahead
    events = proto.receive_navdata(pkt(seq + 100_000, battery=3), t)
    assert any(isinstance(e, NavdataRejected) and "sequence jumped" in e.error for e in events)
    assert battery(proto) == 100
    # the real drone goes on and is still heard
    for i in range(1, 20):
        seq += 1
        events = proto.receive_navdata(pkt(seq), t + 0.066 * i)
        assert any(isinstance(e, NavdataReceived) for e in events)
    assert proto.latest is not None and proto.latest.sequence == seq
    # a forged packet with a plausible sequence: its battery is not believed
    events = proto.receive_navdata(pkt(seq + 1, battery=3), t + 1.3)
    assert battery(proto) == 100
    assert any(isinstance(e, NavdataRejected) and "no discharge" in e.error for e in events)
    # nor is a burst of forged packets interleaved with the real drone's
    for i in range(30):
        seq += 2
        proto.receive_navdata(pkt(seq - 1, battery=3), t + 1.4 + 0.066 * i)
        proto.receive_navdata(pkt(seq, battery=99), t + 1.4 + 0.066 * i + 0.01)
        assert battery(proto) >= 99
    assert proto.state is LinkState.READY
    assert proto.plausibility.doubt  # and the driver says it doubts the stream


def attack(
    proto: DriverProtocol, t: float, seq: int, forged_state: DroneState
) -> tuple[float, int]:
    """3 s of the campaign's attack: forged 1, 2, 3… at 30 Hz, battery 3 %, between the drone's
    own packets at 15 Hz (battery 100 %). Returns the time and sequence reached."""
    events = []
    for i in range(90):
        now = t + i / 30
        events += proto.receive_navdata(pkt(i + 1, battery=3, state=forged_state), now)
        assert battery(proto) == 100
        if i % 2 == 1:
            seq += 1
            events += proto.receive_navdata(pkt(seq), now + 0.005)
            assert proto.latest is not None and proto.latest.sequence == seq
    doubts = [e for e in events if isinstance(e, NavdataDoubt)]
    assert len(doubts) == 1 and "sequence" in doubts[0].reason
    assert sum(isinstance(e, NavdataRejected) for e in events) == 90
    return t + 3.0, seq


def test_a_forged_restart_is_dropped_and_the_drones_stream_keeps_flowing() -> None:
    proto, t, seq = streaming()
    plain = DroneState.NAVDATA_DEMO | DroneState.FLY
    t, seq = attack(proto, t, seq, plain)
    assert proto.plausibility.dropped == 90
    assert proto.state is LinkState.READY
    # the attack stops: the drone's stream, alone again, is trusted after trust_again_s
    events = []
    for k in range(1, round(6.0 / PERIOD)):
        seq += 1
        events += proto.receive_navdata(pkt(seq), t + k * PERIOD)
    assert [e for e in events if isinstance(e, NavdataTrusted)]
    assert not proto.plausibility.doubt


def test_a_forged_restart_claiming_the_drones_restart_bits_is_dropped_too() -> None:
    proto, t, seq = streaming()
    claims = DroneState.NAVDATA_DEMO | DroneState.COM_WATCHDOG | DroneState.NAVDATA_BOOTSTRAP
    attack(proto, t, seq, claims)
    assert proto.state is LinkState.READY and proto.handshake_done  # no redone handshake


def test_a_forger_racing_ahead_of_the_numbering_is_noticed() -> None:
    """Forged packets one ahead of the drone's, plausible battery and all, make the drone's own
    packets look stale: two senders on one address, so the stream is doubted."""
    proto, t, seq = streaming()
    events = []
    for k in range(1, 16):
        now = t + k * PERIOD
        events += proto.receive_navdata(pkt(seq + 1, battery=99), now)  # the forger, first
        seq += 1
        events += proto.receive_navdata(pkt(seq, battery=100), now + 0.002)  # the drone
    doubts = [e for e in events if isinstance(e, NavdataDoubt)]
    assert len(doubts) == 1 and "sequence" in doubts[0].reason


def test_a_watchdog_restart_is_followed_once_the_old_stream_is_silent() -> None:
    """ARDroneLib resets its sequence on the COM watchdog bit; here only once the old stream
    has been silent for resync_quiet_s and the new numbering continues: well before the link
    would be declared lost."""
    proto, t, seq = streaming()
    for k in range(1, 5):
        seq += 1
        proto.receive_navdata(pkt(seq), t + k * PERIOD)
    t_last = t + 4 * PERIOD
    restarted = DroneState.NAVDATA_DEMO | DroneState.FLY | DroneState.COM_WATCHDOG
    followed_at = None
    for k in range(1, 8):
        now = t_last + 0.1 + k * PERIOD
        events = proto.receive_navdata(pkt(k, state=restarted), now)
        assert not [e for e in events if isinstance(e, LinkLost | NavdataDoubt)]
        if proto.latest is not None and proto.latest.sequence == k and followed_at is None:
            followed_at = now
    assert followed_at is not None
    assert CFG.resync_quiet_s <= followed_at - t_last < 0.5  # before the link timeout
    assert not proto.plausibility.doubt


def test_a_restart_without_the_drones_evidence_waits_for_the_link_to_be_lost() -> None:
    proto, t, seq = streaming()
    kinds: list[type] = []
    for k in range(1, 12):
        kinds += [type(e) for e in proto.receive_navdata(pkt(k), t + k * PERIOD)]
        if LinkLost not in kinds:
            assert proto.latest is not None and proto.latest.sequence == seq
    assert LinkLost in kinds and LinkRestored in kinds  # after 0.5 s of silence: followed
    assert proto.latest is not None and proto.latest.sequence == 11


# ---------------------------------------------------------------------------- battery


def test_normal_discharge_and_jumps_after_silence_pass_untouched() -> None:
    p = NavdataPlausibility()
    for i in range(200):  # 1 % every 2 s: every packet believed
        nav = Navdata(DroneState(0), i + 1, demo=Demo(battery_pct=100 - i // 30))
        v = p.check(nav, i * 0.066)
        assert v.navdata == nav and v.reason is None
    # the old stream is quiet, the new numbering far ahead is consistent -> followed
    p2 = NavdataPlausibility()
    p2.check(Navdata(DroneState(0), 10, demo=Demo()), 0.0)
    verdicts = [
        p2.check(Navdata(DroneState(0), 50_000 + k, demo=Demo()), 1.0 + k / 15) for k in range(4)
    ]
    assert [v.navdata is not None for v in verdicts] == [False, False, True, True]


def test_a_collapse_no_discharge_explains_is_never_believed_in_flight() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    proto.receive_navdata(pkt(6, battery=100), t)
    events = []
    for i in range(1, 100):  # 6.6 s of consistent packets at 9 %
        events += proto.receive_navdata(pkt(6 + i, battery=9), t + 0.066 * i)
        assert battery(proto) == 100
    assert [e for e in events if isinstance(e, NavdataDoubt) and "battery" in e.reason]


def test_on_the_ground_a_drop_is_believed_after_consistent_packets() -> None:
    """Motors off, a low reading only refuses a take-off: believed after battery_confirm_s."""
    proto = DriverProtocol()
    t = handshake(proto)
    landed = {"state": DroneState.NAVDATA_DEMO, "ctrl": CtrlState.LANDED << 16}
    proto.receive_navdata(pkt(6, battery=100, **landed), t)  # type: ignore[arg-type]
    levels = []
    for i in range(1, 25):
        proto.receive_navdata(pkt(6 + i, battery=9, **landed), t + 0.066 * i)  # type: ignore[arg-type]
        levels.append(battery(proto))
    assert levels[0] == 100  # not from one packet
    assert 9 in levels[14:17] and levels[-1] == 9  # after a second of consistent packets
    assert not proto.plausibility.doubt


def test_a_sag_under_load_is_believed_only_once_it_has_lasted() -> None:
    env = BatteryEnvelope(CFG)
    t = 0.0
    for _ in range(30):  # hovering at 30 %
        assert env.check(30, t, 1.0, True).report_pct == 30
        t += PERIOD
    # a climb: a worn cell sags 15 points; the climb lasts 1.5 s, then back to 29 at hover
    for _ in range(round(1.5 / PERIOD)):
        v = env.check(15, t, 1.5, True)
        assert v.report_pct == 30 and not v.implausible
        t += PERIOD
    for _ in range(10):
        assert env.check(29, t, 1.0, True).report_pct == 29
        t += PERIOD
    # the cell now sags at hover too: 14 % for 3 s -> believed, nothing suspicious
    reports = []
    for _ in range(round(3.5 / PERIOD)):
        v = env.check(14, t, 1.0, True)
        assert not v.implausible
        reports.append(v.report_pct)
        t += PERIOD
    first = reports.index(14)
    assert 3.0 <= first * PERIOD < 3.2
    assert all(r == 29 for r in reports[:first])


def test_a_sag_beyond_the_model_is_implausible() -> None:
    env = BatteryEnvelope(CFG)
    env.check(60, 0.0, 1.0, True)
    # at hover load the model allows 15 points of sag, plus 3 of jitter on either reading and
    # 2 %/s of drain: 39 fits a packet later, 38 does not
    assert not env.check(39, PERIOD, 1.0, True).implausible
    env2 = BatteryEnvelope(CFG)
    env2.check(60, 0.0, 1.0, True)
    assert env2.check(38, PERIOD, 1.0, True).implausible


def test_a_battery_rising_in_flight_is_implausible() -> None:
    """A forger pushing the reading up to keep a drone flying on an empty pack."""
    env = BatteryEnvelope(CFG)
    for k in range(10):
        env.check(14, k * PERIOD, 1.0, True)
    v = env.check(60, 10 * PERIOD, 1.0, True)
    assert v.implausible and v.report_pct == 14
    # landed, the voltage recovers without load: a rise is fine
    assert env.check(20, 30.0, 0.0, False).report_pct == 20


def test_a_reading_that_is_not_a_percentage_is_implausible() -> None:
    env = BatteryEnvelope(CFG)
    env.check(80, 0.0, 0.0, False)
    v = env.check(4_000_000_000, 0.1, 0.0, False)
    assert v.implausible and v.report_pct == 80


# ---------------------------------------------------------------------------- properties

forged_states = st.sampled_from(
    [
        DroneState.NAVDATA_DEMO,
        DroneState.NAVDATA_DEMO | DroneState.FLY,
        DroneState.NAVDATA_DEMO | DroneState.FLY | DroneState.COM_WATCHDOG,
        DroneState.NAVDATA_BOOTSTRAP | DroneState.COM_WATCHDOG,
        DroneState(0xFFFFFFFF),
    ]
)


@settings(deadline=None, max_examples=150)  # shared, loaded CI machine: no per-example deadline
@given(
    st.lists(
        st.tuples(
            st.one_of(  # off the drone's numbering: behind it, or far ahead
                st.integers(min_value=-10_000, max_value=0),
                st.integers(min_value=1001, max_value=2**31),
            ),
            forged_states,
            st.integers(min_value=0, max_value=2**32 - 1),  # battery, any u32
            st.integers(min_value=0, max_value=4),  # forged packets before the next real one
        ),
        max_size=60,
    )
)
def test_forged_packets_off_the_numbering_never_displace_the_drone(
    forged: list[tuple[int, DroneState, int, int]],
) -> None:
    """Every packet of the drone's own stream is followed, with its own battery, whatever is
    sent between them off its numbering (any state bits, any battery, any rate)."""
    proto, t, seq = streaming()
    for offset, state, level, burst in forged:
        for b in range(burst):
            fake = Navdata(
                state=state,
                sequence=max(0, seq + offset) & 0xFFFFFFFF,
                demo=Demo(ctrl_state=HOVERING, battery_pct=level),
            )
            proto.receive_navdata(encode_navdata(fake), t + 0.001 * (b + 1))
        seq += 1
        t += PERIOD
        proto.receive_navdata(pkt(seq, battery=100), t)
        assert proto.latest is not None and proto.latest.sequence == seq
        assert battery(proto) == 100
    assert proto.state is LinkState.READY


@settings(deadline=None, max_examples=150)
@given(
    st.lists(
        st.tuples(
            st.integers(min_value=-5, max_value=2000),  # any forged numbering, racing included
            st.integers(min_value=0, max_value=100),
            st.floats(min_value=-3000, max_value=3000),  # forged vz: any claimed climb
        ),
        min_size=1,
        max_size=40,
    )
)
def test_no_forgery_lowers_the_battery_faster_than_the_model_allows(
    forged: list[tuple[int, int, float]],
) -> None:
    """Whatever is forged, racing ahead of the drone's numbering included, the reported battery
    in flight falls no faster than the jitter plus the drain slope allow: a critical level
    needs minutes of consistent lies, not a second (and the stream is doubted meanwhile)."""
    proto, t, seq = streaming()
    start = t
    for offset, level, vz in forged:
        fake = packet(max(1, seq + offset), level, ctrl=HOVERING, vz_mm_s=vz)
        proto.receive_navdata(encode_navdata(fake), t + 0.01)
        seq += 1
        t += PERIOD
        proto.receive_navdata(pkt(seq, battery=100), t)
        floor = 100 - CFG.battery_jitter_pct - CFG.battery_max_drop_pct_s * (t - start)
        assert battery(proto) >= math.floor(floor)


@settings(deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(min_value=0, max_value=2**32 - 1),
            st.sampled_from([DroneState(0), DroneState.COM_WATCHDOG, DroneState.NAVDATA_BOOTSTRAP]),
            st.floats(min_value=0.0, max_value=1.0),
        ),
        max_size=50,
    )
)
def test_the_guard_leaves_a_live_stream_only_on_the_drones_evidence(
    packets: list[tuple[int, DroneState, float]],
) -> None:
    """Any sequence of numbers, bits and gaps: the followed number goes down only for a packet
    with the restart bits after the old stream was silent for resync_quiet_s."""
    guard = SequenceGuard(CFG)
    now = 0.0
    for seq, state, gap in packets:
        before, last_at = guard.last_seq, guard.last_at
        now += gap
        followed = guard.check(Navdata(state, seq), now) is None
        if followed and before is not None and last_at is not None and seq <= before:
            assert state & (DroneState.COM_WATCHDOG | DroneState.NAVDATA_BOOTSTRAP)
            assert now - last_at >= CFG.resync_quiet_s
        if not followed:
            assert guard.last_seq == before


@given(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(list(CtrlState)))
def test_the_load_a_packet_implies_is_bounded(vz: float, ctrl: CtrlState) -> None:
    nav = Navdata(DroneState(0), 1, demo=Demo(ctrl_state=ctrl << 16, vz_mm_s=vz))
    load = load_of(nav)
    assert 0.0 <= load <= 1.5 and not math.isnan(load)
