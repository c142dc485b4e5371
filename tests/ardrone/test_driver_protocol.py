"""DriverProtocol alone (no simulator): handshake, AT stream, queue jumping, watchdog, link loss."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drone.ardrone import at
from drone.ardrone.errors import ATEncodeError, DriverNotStartedError
from drone.ardrone.navdata import CtrlState, Demo, DroneState, Navdata, encode_navdata
from drone.ardrone.protocol import (
    DriverProtocol,
    HandshakeDone,
    LinkLost,
    LinkRestored,
    LinkState,
    NavdataReceived,
    NavdataRejected,
)


def nav(seq: int, state: DroneState = DroneState.NAVDATA_DEMO, demo: bool = True) -> bytes:
    d = Demo(ctrl_state=CtrlState.LANDED << 16) if demo else None
    return encode_navdata(Navdata(state=state, sequence=seq, demo=d))


def sent(proto: DriverProtocol, now: float) -> list[at.ATPacket]:
    return [p for d in proto.datagrams_due(now) for p in at.parse_at(d)]


def names(packets: list[at.ATPacket]) -> list[str]:
    return [p.command.NAME for p in packets]


def handshake(proto: DriverProtocol) -> float:
    """Drive the bootstrap → CONFIG → ACK → CTRL=5 → demo handshake; returns the time reached."""
    proto.connect(0.0)
    assert proto.navdata_requests_due(0.0) == [b"\x01\x00\x00\x00"]
    sent(proto, 0.0)
    proto.receive_navdata(nav(1, DroneState.NAVDATA_BOOTSTRAP, demo=False), 0.05)
    assert proto.state is LinkState.CONFIGURING
    cmds = sent(proto, 0.06)
    assert at.Config("general:navdata_demo", "TRUE") in [p.command for p in cmds]
    proto.receive_navdata(nav(2, DroneState.NAVDATA_BOOTSTRAP | DroneState.COMMAND, False), 0.08)
    assert at.Ctrl(5, 0) in [p.command for p in sent(proto, 0.1)]
    proto.receive_navdata(nav(3, DroneState.NAVDATA_DEMO | DroneState.COMMAND), 0.12)
    proto.receive_navdata(nav(4, DroneState.NAVDATA_DEMO), 0.13)
    sent(proto, 0.14)  # notices the ACK bit cleared
    events = proto.receive_navdata(nav(5, DroneState.NAVDATA_DEMO), 0.15)
    assert any(isinstance(e, HandshakeDone) for e in events)
    assert proto.state is LinkState.READY and proto.handshake_done
    return 0.15


def test_handshake_sequence() -> None:
    handshake(DriverProtocol())


def test_commands_before_connect_raise() -> None:
    with pytest.raises(DriverNotStartedError):
        DriverProtocol().takeoff()


def test_at_stream_is_at_least_30_hz_with_ref_and_pcmd_and_increasing_seq() -> None:
    proto = DriverProtocol()
    proto.connect(0.0)
    packets: list[at.ATPacket] = []
    datagrams = 0
    t = 0.0
    while t < 1.0:
        out = proto.datagrams_due(t)
        datagrams += len(out)
        packets += [p for d in out for p in at.parse_at(d)]
        t += 0.001
    assert datagrams >= 30
    assert names(packets[:2]) == ["REF", "PCMD"]
    seqs = [p.seq for p in packets]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs) and seqs[0] == 1


def test_move_clamps_and_zero_is_hover_and_nan_raises() -> None:
    proto = DriverProtocol()
    handshake(proto)
    proto.move(-3.0, 0.5, 2.0, 0.0)
    pcmd = next(p.command for p in sent(proto, 1.0) if isinstance(p.command, at.Pcmd))
    assert (pcmd.flag, pcmd.roll, pcmd.pitch, pcmd.gaz, pcmd.yaw) == (1, -1.0, 0.5, 1.0, 0.0)
    proto.move(0, 0, 0, 0)
    pcmd = next(p.command for p in sent(proto, 2.0) if isinstance(p.command, at.Pcmd))
    assert pcmd == at.Pcmd.hover()
    with pytest.raises(ValueError, match="finite"):
        proto.move(float("nan"), 0, 0, 0)
    with pytest.raises(ATEncodeError):
        proto.config('bad"key', "1")
    with pytest.raises(ValueError):
        proto.camera(7)


def test_takeoff_and_land_bits() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    proto.takeoff()
    ref = sent(proto, t + 0.1)[0].command
    assert isinstance(ref, at.Ref) and ref.takeoff_bit
    proto.land()
    ref = sent(proto, t + 0.101)[0].command  # due at once, not at the next 30 ms tick
    assert isinstance(ref, at.Ref) and not ref.takeoff_bit and not ref.emergency_bit


@pytest.mark.parametrize("urgent", ["land", "emergency"])
def test_land_and_emergency_jump_the_queue(urgent: str) -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    for i in range(40):  # more one-shot commands than fit in one datagram
        proto.flat_trim()
        proto.config(f"custom:k{i}", "v" * 30)
    first = proto.datagrams_due(t + 0.1)
    assert len(first) == 1
    assert not proto.datagrams_due(t + 0.101)  # nothing due yet
    getattr(proto, urgent)()
    out = proto.datagrams_due(t + 0.101)  # due immediately
    assert len(out) == 1
    head = at.parse_at(out[0])[0].command
    assert isinstance(head, at.Ref)
    assert head.emergency_bit == (urgent == "emergency") and not head.takeoff_bit


def test_emergency_not_resent_when_already_in_emergency_and_reset_toggles() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    proto.receive_navdata(nav(10, DroneState.NAVDATA_DEMO | DroneState.EMERGENCY), t + 0.1)
    sent(proto, t + 0.2)
    proto.emergency()  # already in emergency: a toggle would undo it
    assert not sent(proto, t + 0.25)[0].command.emergency_bit  # type: ignore[union-attr]
    proto.reset()
    assert sent(proto, t + 0.26)[0].command.emergency_bit  # type: ignore[union-attr]
    proto.receive_navdata(nav(11, DroneState.NAVDATA_DEMO), t + 0.3)  # emergency cleared
    assert not sent(proto, t + 0.4)[0].command.emergency_bit  # type: ignore[union-attr]


def test_reset_right_after_the_emergency_is_seen_still_makes_an_edge() -> None:
    """The bit toggles on its rising edge (SDK 2.0 §6.6): a reset asked before any datagram
    went out with the bit cleared would only prolong the emergency's hold, and be lost."""
    proto = DriverProtocol()
    t = handshake(proto)
    proto.emergency()
    assert sent(proto, t + 0.01)[0].command.emergency_bit  # type: ignore[union-attr]
    proto.receive_navdata(nav(10, DroneState.NAVDATA_DEMO | DroneState.EMERGENCY), t + 0.02)
    proto.reset()  # before the next datagram
    bits = [sent(proto, t + 0.03 + k * 1e-3)[0].command.emergency_bit for k in range(2)]  # type: ignore[union-attr]
    assert bits == [False, True]  # cleared once, at once, then the bit itself


def test_comwdg_answers_the_watchdog_bit() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    assert "COMWDG" not in names(sent(proto, t + 0.1))
    proto.receive_navdata(nav(10, DroneState.NAVDATA_DEMO | DroneState.COM_WATCHDOG), t + 0.11)
    assert "COMWDG" in names(sent(proto, t + 0.2))
    assert "COMWDG" not in names(sent(proto, t + 0.3))


def test_link_loss_reinit_and_restore() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    assert proto.poll_events(t + 0.4) == []
    events = proto.poll_events(t + 0.5)
    assert [type(e) for e in events] == [LinkLost]
    assert proto.state is LinkState.LOST and not proto.link_up
    assert proto.navdata_requests_due(t + 0.5) == [b"\x01\x00\x00\x00"]  # re-init
    assert proto.navdata_requests_due(t + 0.6) == []
    assert proto.navdata_requests_due(t + 1.0) == [b"\x01\x00\x00\x00"]
    assert sent(proto, t + 1.0)  # the AT stream keeps going while lost
    events = proto.receive_navdata(nav(1, DroneState.NAVDATA_DEMO), t + 1.1)  # drone restarted seq
    kinds = [type(e) for e in events]
    assert LinkRestored in kinds and NavdataReceived in kinds
    assert proto.state is LinkState.READY
    assert sent(proto, t + 1.2)[0].seq == 1  # AT sequence restarted


def test_bad_and_stale_navdata() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    events = proto.receive_navdata(b"garbage", t + 0.01)
    assert [type(e) for e in events] == [NavdataRejected]
    stale = proto.receive_navdata(nav(4, DroneState.NAVDATA_DEMO), t + 0.02)
    assert [type(e) for e in stale] == [NavdataRejected] and "stale" in stale[0].error
    assert proto.latest is not None and proto.latest.sequence == 5


def test_drone_reboot_in_bootstrap_redoes_the_handshake() -> None:
    """A drone whose numbering restarts in bootstrap while its old stream has gone silent is
    followed after three packets (drone/ardrone/plausibility.py), and the handshake is redone."""
    proto = DriverProtocol()
    t = handshake(proto)
    for k in (1, 2, 3):
        proto.receive_navdata(nav(k, DroneState.NAVDATA_BOOTSTRAP, demo=False), t + 0.3 + 0.05 * k)
    assert proto.state is LinkState.CONFIGURING and not proto.handshake_done
    assert at.Config("general:navdata_demo", "TRUE") in [p.command for p in sent(proto, t + 0.46)]


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(st.lists(st.binary(max_size=200), max_size=20))
def test_arbitrary_datagrams_never_crash_the_driver(datagrams: list[bytes]) -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    for i, d in enumerate(datagrams):
        events = proto.receive_navdata(d, t + 0.001 * (i + 1))
        assert all(not isinstance(e, NavdataReceived) or e.navdata for e in events)
        sent(proto, t + 0.001 * (i + 1))
    assert proto.state is LinkState.READY


def test_unacknowledged_config_is_resent_after_a_link_loss() -> None:
    proto = DriverProtocol()
    t = handshake(proto)
    proto.config("video:video_channel", "1")
    assert at.Config("video:video_channel", "1") in [p.command for p in sent(proto, t + 0.1)]
    assert [type(e) for e in proto.poll_events(t + 0.6)] == [LinkLost]
    proto.receive_navdata(nav(1, DroneState.NAVDATA_DEMO), t + 1.0)
    assert at.Config("video:video_channel", "1") in [p.command for p in sent(proto, t + 1.1)]
