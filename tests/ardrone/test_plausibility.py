"""Forged navdata (issue 14) reproduced against the driver's protocol, sans-I/O.

The AR.Drone's navdata has no authentication. Before: one forged packet with battery 3 % made
the console land a drone at 85 %, and its far-ahead sequence number made the driver drop every
real packet after it as stale. Now the driver holds both until consistent packets confirm them.
"""

from __future__ import annotations

from test_driver_protocol import handshake

from drone.ardrone.driver import DriverProtocol, LinkState, NavdataReceived, NavdataRejected
from drone.ardrone.navdata import CtrlState, Demo, DroneState, Navdata, encode_navdata
from drone.ardrone.plausibility import NavdataPlausibility

FLYING = CtrlState.FLYING << 16


def pkt(seq: int, battery: int = 100) -> bytes:
    demo = Demo(ctrl_state=FLYING, battery_pct=battery)
    return encode_navdata(Navdata(state=DroneState.NAVDATA_DEMO, sequence=seq, demo=demo))


def battery(proto: DriverProtocol) -> int:
    assert proto.latest is not None and proto.latest.demo is not None
    return proto.latest.demo.battery_pct


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
    assert any(isinstance(e, NavdataRejected) and "implausible battery" in e.error for e in events)
    # nor is a burst of forged packets interleaved with the real drone's
    for i in range(30):
        seq += 2
        proto.receive_navdata(pkt(seq - 1, battery=3), t + 1.4 + 0.066 * i)
        proto.receive_navdata(pkt(seq, battery=99), t + 1.4 + 0.066 * i + 0.01)
        assert battery(proto) >= 99
    assert proto.state is LinkState.READY


def test_a_real_battery_collapse_is_believed_after_consistent_packets() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    seq = 5
    proto.receive_navdata(pkt(6, battery=100), t)
    levels = []
    for i in range(1, 25):
        seq = 6 + i
        proto.receive_navdata(pkt(seq, battery=9), t + 0.066 * i)
        levels.append(battery(proto))
    assert levels[0] == 100  # not from one packet
    assert levels[-1] == 9  # but after a second of consistent packets
    assert 9 in levels[14:17]  # ... and not much later than that


def test_normal_discharge_and_restarts_pass_untouched() -> None:
    p = NavdataPlausibility()
    for i in range(200):  # 1 % every 2 s: every packet believed
        nav = Navdata(DroneState(0), i + 1, demo=Demo(battery_pct=100 - i // 30))
        v = p.check(nav, i * 0.066)
        assert v.navdata == nav and v.reason is None
    # a rebooted drone: the old stream is quiet, the new one is consistent -> believed
    p2 = NavdataPlausibility()
    p2.check(Navdata(DroneState(0), 10, demo=Demo()), 0.0)
    verdicts = [
        p2.check(Navdata(DroneState(0), 50_000 + k, demo=Demo()), 1.0 + k / 15) for k in range(4)
    ]
    assert [v.navdata is not None for v in verdicts] == [False, False, True, True]
