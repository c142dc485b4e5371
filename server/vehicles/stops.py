"""Each stop runs once, whichever road brings it first, and never after it was superseded.

The page sends every Land, Hover and Emergency down two roads at once with one id (the console:
REST → the bus; the vehicle's safety door). :class:`StopLedger` is where a vehicle decides
what a stop that arrives means: run it (first arrival), answer with the first delivery (the copy
from the other road), or drop it (the operator has issued a newer command since: ``supersede``).
Pure: time is passed in (unix seconds, the clock ``issued`` is on); bounded memory.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import TypeVar

V = TypeVar("V")

# Ids remembered (delivered and superseded, each): a page sends a few stops a minute, so this
# spans hours; an id pushed out only loses its dedupe, a stop then runs again (harmless: land,
# hover and emergency are idempotent on the drone: the driver never toggles emergency off).
CAPACITY = 1024
LATE_NOTE_S = 0.5  # a delivery later than this after ``issued`` says how late in its detail


@dataclass(frozen=True)
class Delivery:
    action: str
    road: str
    at: float  # unix seconds
    late_s: float | None


@dataclass(frozen=True)
class StopVerdict:
    """What to do with a stop that arrived, and what to answer."""

    run: bool  # send it to the drone now
    accepted: bool  # the stop is (or was) carried out
    detail: str
    delivered: float | None  # when it ran (this arrival or the first)
    road: str  # the road it ran from
    late_s: float | None  # delivered - issued (None: issued not given)


def describe_late(late_s: float | None) -> str:
    if late_s is None or late_s < LATE_NOTE_S:
        return ""
    return f" {late_s:.1f} s after it was issued"


class StopLedger:
    """Stop ids delivered and superseded (see the module docstring)."""

    def __init__(self, capacity: int = CAPACITY) -> None:
        self.capacity = capacity
        self._delivered: OrderedDict[str, Delivery] = OrderedDict()
        self._superseded: OrderedDict[str, float] = OrderedDict()

    def admit(
        self, stop_id: str, action: str, issued: float | None, road: str, now: float
    ) -> StopVerdict:
        """A stop ``stop_id`` arrived by ``road``: run it, or say why not."""
        first = self._delivered.get(stop_id)
        if first is not None:
            return StopVerdict(
                False,
                True,
                f"{first.action} {stop_id} was already delivered by the {first.road} road"
                f"{describe_late(first.late_s)}; this copy by the {road} road was not run again",
                first.at,
                first.road,
                first.late_s,
            )
        if stop_id in self._superseded:
            return StopVerdict(
                False,
                False,
                f"{action} {stop_id} was superseded by a newer command: not run",
                None,
                road,
                None,
            )
        late = None if issued is None else max(0.0, now - issued)
        self._remember(self._delivered, stop_id, Delivery(action, road, now, late))
        return StopVerdict(True, True, f"{action} delivered{describe_late(late)}", now, road, late)

    def supersede(
        self, ids: tuple[str, ...], now: float
    ) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """Drop these stops if they arrive later; returns (dropped, already run)."""
        dropped: list[str] = []
        too_late: list[str] = []
        for stop_id in ids:
            if stop_id in self._delivered:
                too_late.append(stop_id)
            else:
                self._remember(self._superseded, stop_id, now)
                dropped.append(stop_id)
        return tuple(dropped), tuple(too_late)

    def _remember(self, table: OrderedDict[str, V], key: str, value: V) -> None:
        table[key] = value
        table.move_to_end(key)
        while len(table) > self.capacity:
            table.popitem(last=False)

    def delivered(self, stop_id: str) -> Delivery | None:
        return self._delivered.get(stop_id)
