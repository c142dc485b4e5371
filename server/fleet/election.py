"""Who holds the fleet's central role, decided through the bus; sans-I/O, time passed in.

Every console on the bus declares its presence (its one liveliness token,
``uavc/<fleet>/console/<name>/alive``); the one holding the central role also declares
``uavc/<fleet>/central/alive`` and ``uavc/<fleet>/central/alive/<name>``. The rule, the same in
every console so that all of them reach the same answer from the same view:

1. A holder keeps the role while it is alive (the incumbent stays central when a console with a
   lower name joins: a takeover costs the fleet a pause, a lower name gains it nothing).
2. Two holders (two consoles that claimed before each saw the other): the one with the lowest
   name keeps it, the others release at once.
3. No holder: the consoles alive claim in order of their names, the lowest at once, the ``k``-th
   after ``k * backoff_s`` without a holder (so a console that is alive but does not claim, a hung
   one, does not leave the fleet without a central for good).
4. A console claims nothing in its first ``settle_s``: its view of the bus is still arriving.

Feed :meth:`Election.observe` the view (consoles alive, holders) and ``now``; it returns what to
do (:class:`Action`) and keeps whether this console holds the role (:attr:`Election.central`).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass

SETTLE_S = 0.5  # Zenoh's liveliness history arrives within milliseconds on a live link
BACKOFF_S = 1.0  # the k-th console in name order claims after k seconds without a holder


class Action(enum.Enum):
    """What the console must do on the bus after an observation."""

    NONE = "none"
    CLAIM = "claim"  # declare the central tokens: this console is central from now on
    RELEASE = "release"  # undeclare them: another console keeps the role


@dataclass(frozen=True)
class View:
    """What a console sees on the bus: the consoles alive and the holders of the role."""

    consoles: frozenset[str]
    holders: frozenset[str]

    @classmethod
    def of(cls, consoles: Iterable[str], holders: Iterable[str]) -> View:
        return cls(frozenset(consoles), frozenset(holders))


class Election:
    """One console's side of the election (see the module docstring).

    Args:
        me: this console's name (unique in the fleet: names order the consoles).
        start: when this console joined the bus (its clock).
        settle_s: no claim before ``start + settle_s``.
        backoff_s: the rank-``k`` console claims after ``k * backoff_s`` without a holder.
    """

    def __init__(
        self, me: str, start: float, *, settle_s: float = SETTLE_S, backoff_s: float = BACKOFF_S
    ) -> None:
        self.me = me
        self.start = start
        self.settle_s = settle_s
        self.backoff_s = backoff_s
        self.central = False
        self.holder: str | None = None  # the console holding the role, as last seen
        self._no_holder_since: float = start
        self.changes = 0  # times this console claimed or released

    def observe(self, view: View, now: float) -> Action:
        """The view at ``now``; returns what to do (and updates :attr:`central`)."""
        others = view.holders - {self.me}
        if self.central:
            if others and min(others) < self.me:
                self.central = False
                self.holder = min(others)
                self._no_holder_since = math.inf
                self.changes += 1
                return Action.RELEASE
            self.holder = self.me
            return Action.NONE
        if others:
            self.holder = min(others)
            self._no_holder_since = math.inf
            return Action.NONE
        if self.holder is not None or self._no_holder_since == math.inf:
            self.holder = None
            self._no_holder_since = now
        if now < self.start + self.settle_s:
            return Action.NONE
        rank = sorted(view.consoles | {self.me}).index(self.me)
        if now - self._no_holder_since >= rank * self.backoff_s:
            self.central = True
            self.holder = self.me
            self.changes += 1
            return Action.CLAIM
        return Action.NONE

    def resign(self) -> Action:
        """This console stops (shutting down): release the role if it holds it."""
        if not self.central:
            return Action.NONE
        self.central = False
        self.holder = None
        self.changes += 1
        return Action.RELEASE
