"""The replay timeline (sans-I/O): play, pause, seek and speed on a given clock."""

from __future__ import annotations

import pytest

from server.recorder.replay import Played, Timeline

S = 1_000_000_000


def msgs() -> list[Played]:
    out = []
    for i in range(10):  # a state message every second, a pose every half second
        out.append(Played(100 * S + i * S, "/state", "t/S", {"n": i}))
        out.append(Played(100 * S + i * S + S // 2, "/pose", "t/P", {"n": i}))
    return out


def test_plays_in_scaled_time_and_stops_at_the_end() -> None:
    tl = Timeline(msgs(), speed=2.0)
    assert tl.duration_s == 9.5
    first = tl.play(now=0.0)
    assert [(p.topic, p.msg["n"]) for p in first] == [("/state", 0)]
    assert tl.next_due_in(0.0) == pytest.approx(0.25)  # the first pose, 0.5 s at 2×
    # 2 s of recording in 1 s: pose 0, state 1, pose 1, state 2 (at exactly 2 s)
    assert [p.msg["n"] for p in tl.due(1.0)] == [0, 1, 1, 2]
    assert tl.due(1.0) == []
    rest = tl.due(100.0)
    assert len(rest) == 20 - 5 and not tl.playing and tl.position_ns == tl.end_ns
    again = tl.play(now=200.0)  # at the end, play starts over
    assert tl.playing and again[0].msg["n"] == 0


def test_pause_seek_and_speed() -> None:
    tl = Timeline(msgs())
    tl.play(0.0)
    tl.due(2.2)
    tl.pause(2.2)
    assert tl.due(50.0) == [] and tl.status()["position_s"] == pytest.approx(2.2)
    state = tl.seek(100 * S + 6 * S + S // 4, now=50.0)  # 6.25 s in
    assert [(p.topic, p.msg["n"]) for p in state] == [("/pose", 5), ("/state", 6)]
    back = tl.seek(0, now=50.0)  # clamped to the start
    assert [(p.topic, p.msg["n"]) for p in back] == [("/state", 0)]
    tl.play(60.0)
    tl.set_speed(4.0, 60.0)
    assert [p.msg["n"] for p in tl.due(60.25)] == [0, 1]  # 1 s of recording in 0.25 s
    with pytest.raises(ValueError, match="positive"):
        tl.set_speed(0.0, 61.0)


def test_a_start_after_the_first_message_cuts_the_timeline_there() -> None:
    """An older recording logged its opening state when it was published, minutes before the
    flight: the timeline starts at the flight, and that state is published at the start."""
    early = [Played(10 * S, "/console/state", "t/D", {"n": -1})]
    tl = Timeline(early + msgs(), start_ns=100 * S)
    assert tl.duration_s == 9.5 and tl.status()["position_s"] == 0.0
    first = tl.play(now=0.0)
    assert [(p.topic, p.msg["n"]) for p in first] == [("/console/state", -1), ("/state", 0)]
    assert tl.seek(tl.start_ns, now=1.0)[0].topic == "/console/state"
    assert Timeline(msgs(), start_ns=0).start_ns == 100 * S  # never before the first message
    assert Timeline(msgs(), start_ns=10**12 * S).start_ns == tl.end_ns  # nor after the last
