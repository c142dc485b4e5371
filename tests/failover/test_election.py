"""The central role's election (server.fleet.election): one rule, the same answer everywhere.

A small fake bus steps the consoles in rounds: each console sees the bus as it was some rounds
ago (its own lag, drawn by Hypothesis), consoles join and die at drawn rounds."""

from __future__ import annotations

from dataclasses import dataclass, field

from hypothesis import given, settings
from hypothesis import strategies as st

from server.fleet.election import BACKOFF_S, SETTLE_S, Action, Election, View

DT = 0.1  # seconds a round


@dataclass
class FakeBus:
    """Consoles, the holders' tokens, and the history of both (for lagged views)."""

    elections: dict[str, Election] = field(default_factory=dict)
    holders: set[str] = field(default_factory=set)
    history: list[View] = field(default_factory=list)

    def view(self, lag: int) -> View:
        if not self.history:
            return View.of((), ())
        return self.history[max(0, len(self.history) - 1 - lag)]

    def record(self) -> None:
        self.history.append(View.of(self.elections, self.holders))

    def step(self, now: float, lags: dict[str, int]) -> None:
        self.record()
        for name, e in sorted(self.elections.items()):
            action = e.observe(self.view(lags.get(name, 0)), now)
            if action is Action.CLAIM:
                self.holders.add(name)
            elif action is Action.RELEASE:
                self.holders.discard(name)

    def kill(self, name: str) -> None:
        self.elections.pop(name)
        self.holders.discard(name)


NAMES = st.sampled_from(["a", "b", "c", "d", "e"])


def settle_rounds(n: int, lag: int) -> int:
    return int((SETTLE_S + n * BACKOFF_S) / DT) + 2 * lag + 5


@given(
    st.lists(NAMES, min_size=1, max_size=5, unique=True),
    st.lists(st.integers(0, 3), min_size=5, max_size=5),
    st.lists(st.integers(0, 30), min_size=5, max_size=5),
)
@settings(max_examples=200, deadline=None)
def test_any_join_order_and_lags_end_with_exactly_one_central(
    names: list[str], lags: list[int], joins: list[int]
) -> None:
    bus = FakeBus()
    lag = dict(zip(names, lags, strict=False))
    join = dict(zip(names, joins, strict=False))
    end = max(joins) + settle_rounds(len(names), max(lags))
    for r in range(end):
        now = r * DT
        for name in names:
            if join[name] == r:
                bus.elections[name] = Election(name, now)
        bus.step(now, lag)
    assert len(bus.holders) == 1
    (holder,) = bus.holders
    assert all(e.central == (n == holder) for n, e in bus.elections.items())
    assert all(e.holder == holder for e in bus.elections.values())


@given(st.lists(NAMES, min_size=2, max_size=5, unique=True), st.integers(0, 2))
@settings(max_examples=100, deadline=None)
def test_the_incumbent_keeps_the_role_when_lower_names_join(names: list[str], lag: int) -> None:
    first = max(names)  # the highest name joins first and takes the role
    bus = FakeBus()
    bus.elections[first] = Election(first, 0.0)
    r = 0
    while not bus.holders:
        bus.step(r * DT, {})
        r += 1
    for name in names:
        if name != first:
            bus.elections[name] = Election(name, r * DT)
    for k in range(settle_rounds(len(names), lag)):
        bus.step((r + k) * DT, dict.fromkeys(names, lag))
    assert bus.holders == {first}


@given(st.lists(NAMES, min_size=2, max_size=5, unique=True))
@settings(max_examples=100, deadline=None)
def test_when_the_central_dies_the_lowest_standby_claims_at_its_next_look(
    names: list[str],
) -> None:
    bus = FakeBus()
    for name in names:
        bus.elections[name] = Election(name, 0.0)
    r = 0
    for r in range(settle_rounds(len(names), 0)):
        bus.step(r * DT, {})
    (holder,) = bus.holders
    bus.kill(holder)
    bus.step((r + 1) * DT, {})  # the standbys see the holder's token gone
    assert bus.holders == {min(set(names) - {holder})}


def test_two_claims_at_once_resolve_to_the_lowest_name() -> None:
    a, b = Election("a", 0.0), Election("b", 0.0)
    a.central = b.central = True
    assert b.observe(View.of("ab", "ab"), 5.0) is Action.RELEASE
    assert a.observe(View.of("ab", "ab"), 5.0) is Action.NONE
    assert a.central and not b.central and b.holder == "a"


def test_nobody_claims_while_settling_and_a_hung_lowest_is_passed_over() -> None:
    b = Election("b", 10.0)
    view = View.of("ab", "")  # "a" is alive but never claims
    assert b.observe(view, 10.0 + SETTLE_S / 2) is Action.NONE
    assert b.observe(view, 10.0 + BACKOFF_S - DT) is Action.NONE
    assert b.observe(view, 10.0 + BACKOFF_S) is Action.CLAIM
    assert b.central


def test_resign_releases_only_a_held_role() -> None:
    e = Election("a", 0.0)
    assert e.resign() is Action.NONE
    assert e.observe(View.of("a", ""), SETTLE_S) is Action.CLAIM
    assert e.resign() is Action.RELEASE and not e.central
