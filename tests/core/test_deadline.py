"""The command deadline rule (drone/deadline.py): what expires, what never does, the clock offset.

Pure functions of numbers: no server, no clock read, Hypothesis for the rule and the parsers.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drone.deadline import (
    HARMLESS,
    MAX_AHEAD_S,
    MAX_DEADLINE_S,
    STOPS,
    BadIssued,
    ClockOffset,
    Deadline,
    Deliver,
    Expired,
    ReportGate,
    audit_outcome,
    expires,
    label,
    not_flown,
    parse_issued,
    stamp,
)
from server.settings import Settings, SettingsError

MOTION = ("takeoff", "move", "turn", "goto", "jog", "patrol", "patrol_start", "mission")
NOW = 1_700_000_000.0
deadlines = st.floats(min_value=0.01, max_value=MAX_DEADLINE_S)
ages = st.floats(min_value=0.0, max_value=1e6)


@given(kind=st.sampled_from(sorted(STOPS | HARMLESS)), age=ages, deadline=deadlines)
def test_a_stop_never_expires(kind: str, age: float, deadline: float) -> None:
    verdict = Deadline(deadline).judge(kind, NOW - age, NOW)
    assert isinstance(verdict, Deliver)
    assert not expires(kind)


@given(kind=st.sampled_from(MOTION), age=ages, deadline=deadlines)
def test_a_motion_command_expires_exactly_past_its_deadline(
    kind: str, age: float, deadline: float
) -> None:
    issued = NOW - age
    verdict = Deadline(deadline).judge(kind, issued, NOW)
    assert isinstance(verdict, Expired) == (NOW - issued > deadline)
    assert math.isclose(verdict.age_s, NOW - issued, abs_tol=1e-6)
    if isinstance(verdict, Expired):
        assert verdict.late_s > 0 and verdict.deadline_s == deadline


def test_an_unknown_kind_expires_a_stop_never() -> None:
    # The safe default: anything not known to move nothing is a motion command.
    assert expires("some_new_action")
    assert not any(expires(k) for k in STOPS)


@given(ahead=st.floats(min_value=0.0, max_value=1e6))
def test_a_command_from_the_future_counts_as_just_issued(ahead: float) -> None:
    verdict = Deadline(2.0).judge("takeoff", NOW + ahead, NOW)
    assert verdict == Deliver(0.0)


def test_a_sentence_expires_if_any_of_its_commands_can() -> None:
    rule = Deadline(2.0)
    assert isinstance(rule.judge_all(["land", "takeoff"], NOW - 3, NOW), Expired)
    assert isinstance(rule.judge_all(["land", "hover"], NOW - 300, NOW), Deliver)
    assert isinstance(rule.judge_all(["query"], NOW - 300, NOW), Deliver)
    assert isinstance(rule.judge_all(["takeoff"], NOW - 1.9, NOW), Deliver)


@pytest.mark.parametrize("bad", [0, -1.0, math.nan, math.inf, MAX_DEADLINE_S + 1, True, "2"])
def test_a_deadline_must_be_a_positive_bounded_number(bad: object) -> None:
    with pytest.raises(ValueError):
        Deadline(bad)  # type: ignore[arg-type]


def test_the_setting_is_validated_and_read_from_the_environment() -> None:
    assert Settings().command_deadline_s == 2.0
    assert Settings.from_env({"UAVC_COMMAND_DEADLINE_S": "0.5"}).command_deadline_s == 0.5
    for bad in ("0", "-2", "nan", "1e9"):
        with pytest.raises(SettingsError, match="command_deadline_s"):
            Settings.from_env({"UAVC_COMMAND_DEADLINE_S": bad})


@given(st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(), st.binary()))
def test_parse_issued_gives_seconds_or_the_documented_error(value: object) -> None:
    try:
        out = parse_issued(value)
    except BadIssued as exc:
        assert "issued" in str(exc)
        return
    assert isinstance(out, float) and math.isfinite(out) and out > 0


@given(st.floats(min_value=1e-3, max_value=1e12))
def test_parse_issued_round_trips_numbers_and_header_text(value: float) -> None:
    assert parse_issued(value) == value
    assert parse_issued(repr(value)) == value
    assert parse_issued(f" {value!r} ") == value


@pytest.mark.parametrize("bad", [True, 0, -5, math.nan, math.inf, "soon", "", None, [1.0]])
def test_parse_issued_refuses_what_is_not_unix_seconds(bad: object) -> None:
    with pytest.raises(BadIssued):
        parse_issued(bad)


@given(issued=st.one_of(st.none(), st.floats(min_value=1.0, max_value=NOW + MAX_AHEAD_S)))
def test_stamp_is_never_later_than_arrival(issued: float | None) -> None:
    out = stamp(issued, NOW)
    assert out <= NOW
    assert out == (NOW if issued is None else min(issued, NOW))


def test_stamp_refuses_milliseconds_sent_for_seconds() -> None:
    with pytest.raises(BadIssued, match="milliseconds"):
        stamp(NOW * 1000, NOW)


@given(
    offset=st.floats(min_value=-1e5, max_value=1e5),
    delays=st.lists(st.floats(min_value=0.0, max_value=10.0), min_size=1, max_size=40),
)
def test_clock_offset_is_the_true_offset_less_the_shortest_transit(
    offset: float, delays: list[float]
) -> None:
    clock = ClockOffset(window=50)
    for i, delay in enumerate(delays):
        sent_local = 1000.0 + i * 0.1  # our clock when the remote sent it
        clock.sample(sent_local + offset, sent_local + delay)
    assert clock.offset_s is not None
    assert math.isclose(clock.offset_s, offset - min(delays), abs_tol=1e-6)
    # a remote stamp maps onto our clock no earlier than it really was: never older than it is
    assert clock.to_local(5000.0 + offset) >= 5000.0 - 1e-6


def test_a_burst_of_late_heartbeats_does_not_make_old_commands_look_young() -> None:
    clock = ClockOffset(window=300)
    for i in range(50):  # 5 s of heartbeats, 1 ms in transit
        clock.sample(100.0 + i * 0.1 + 7.0, 100.0 + i * 0.1 + 0.001)
    for i in range(30):  # a 3 s stall: the backlog read at once
        clock.sample(105.0 + i * 0.1 + 7.0, 108.0)
    assert clock.offset_s is not None and math.isclose(clock.offset_s, 7.0 - 0.001)


def test_clock_offset_before_any_sample_and_after_a_clock_step() -> None:
    clock = ClockOffset(window=3)
    assert clock.offset_s is None and clock.to_local(42.0) == 42.0
    for t in (1.0, 2.0, 3.0):
        clock.sample(t + 10.0, t)
    for t in (4.0, 5.0, 6.0):  # the remote clock stepped back 10 s: old samples forgotten
        clock.sample(t, t)
    assert clock.offset_s == 0.0
    clock.sample(math.nan, 7.0)  # ignored
    assert clock.offset_s == 0.0
    with pytest.raises(ValueError):
        ClockOffset(window=0)


def test_the_operator_is_told_how_late_and_the_audit_says_by_how_much() -> None:
    verdict = Deadline(2.0).judge("takeoff", NOW - 5.4, NOW)
    assert isinstance(verdict, Expired)
    assert not_flown(label("takeoff"), verdict) == (
        "Not flown: 'take off' reached the drone 5.4 s after you gave it (deadline 2 s)."
    )
    assert audit_outcome(verdict).startswith("expired: delivered 5.40 s after it was issued")
    assert "3.40 s past the 2 s deadline" in audit_outcome(verdict)
    assert label("return_home") == "return home" and label("jog") == "jog"


def test_report_gate_says_a_late_jog_once_every_interval() -> None:
    gate = ReportGate(interval_s=2.0)
    said = [gate.allow("/cmd_vel", t / 10) for t in range(30)]
    assert said.count(True) == 2 and said[0] and said[20]
    gate.reset("/cmd_vel")
    assert gate.allow("/cmd_vel", 3.0)
