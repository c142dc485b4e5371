"""Command deadlines: a motion command that reaches the drone late is dropped, never flown late.

DESIGN §5: every command carries when the operator gave it (``issued``, Unix seconds of the
console's clock). Where a command is handed to the vehicle — the console when it passes it on,
the vehicle process again when it receives it — :meth:`Deadline.judge` decides: a motion
command (take off, go to, move, turn, jog, patrol, a mission, return home …) older than the
deadline is *expired*: dropped, audited and reported ("Not flown: …"). A stop (emergency, land,
hover) never expires, nor does anything that moves nothing (a query, cancel, describe, help):
one rule, shared by every door and by the stop path.

A vehicle whose clock may differ from the console's converts ``issued`` with a
:class:`ClockOffset` learnt from the console's heartbeat.

Pure: numbers in, verdicts out; time is passed in, nothing here reads a clock.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

# Never expire: a stop must get through however late (DESIGN §5).
STOPS = frozenset({"emergency", "land", "hover"})
# Never expire either: they move nothing (cancel ends the running task and hovers).
HARMLESS = frozenset({"cancel", "query", "describe", "help"})
DEFAULT_DEADLINE_S = 2.0
# A deadline longer than this is no deadline: a command a minute old is from another situation.
MAX_DEADLINE_S = 60.0
# An ``issued`` this far ahead of the receiver's clock is not a clock difference but a wrong
# unit (milliseconds) or a made-up stamp; it is refused rather than allowed to never expire.
MAX_AHEAD_S = 300.0
# How the operator calls an action in a "Not flown" line (an action not listed: its name).
LABELS = {
    "takeoff": "take off",
    "return_home": "return home",
    "goto": "go to",
    "jog": "jog",
    "patrol_start": "patrol",
    "mission": "mission",
}


class BadIssued(ValueError):
    """An ``issued`` stamp that is not Unix seconds (the message says what was wrong)."""


def expires(kind: str) -> bool:
    """Whether a command of ``kind`` (an action name, ``jog``, ``mission``) can expire:
    everything but a stop and the commands that move nothing."""
    return kind not in STOPS and kind not in HARMLESS


@dataclass(frozen=True)
class Deliver:
    """Hand the command over; it is ``age_s`` old."""

    age_s: float


@dataclass(frozen=True)
class Expired:
    """Drop the command: it is ``age_s`` old, past its ``deadline_s``."""

    age_s: float
    deadline_s: float

    @property
    def late_s(self) -> float:
        """How far past the deadline."""
        return self.age_s - self.deadline_s


Verdict = Deliver | Expired


def check_deadline_s(value: float) -> float:
    """``value`` if it is a usable deadline (finite, > 0, at most ``MAX_DEADLINE_S``).

    Raises:
        ValueError: it is not.
    """
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"a command deadline is a number of seconds, not {value!r}")
    if not (math.isfinite(value) and 0 < value <= MAX_DEADLINE_S):
        raise ValueError(
            f"a command deadline must be more than 0 and at most {MAX_DEADLINE_S:g} s, "
            f"not {value!r}"
        )
    return float(value)


@dataclass(frozen=True)
class Deadline:
    """The rule: a command of an expiring kind older than ``deadline_s`` is expired."""

    deadline_s: float = DEFAULT_DEADLINE_S

    def __post_init__(self) -> None:
        check_deadline_s(self.deadline_s)

    def judge(self, kind: str, issued: float, now: float) -> Verdict:
        """The verdict on a ``kind`` command issued at ``issued``, handed over at ``now``
        (both on one clock). An ``issued`` after ``now`` counts as age 0."""
        return self.judge_all((kind,), issued, now)

    def judge_all(self, kinds: tuple[str, ...] | list[str], issued: float, now: float) -> Verdict:
        """One verdict for a sentence of commands: it expires if any of them can."""
        age = max(0.0, now - issued) if math.isfinite(issued) else math.inf
        if age > self.deadline_s and any(expires(k) for k in kinds):
            return Expired(age, self.deadline_s)
        return Deliver(age)


def parse_issued(value: object) -> float:
    """An ``issued`` value as sent (a JSON number, or header text) → Unix seconds.

    Raises:
        BadIssued: not a finite positive number of seconds.
    """
    if isinstance(value, bool):
        raise BadIssued("issued must be a number of Unix seconds, not a boolean")
    if isinstance(value, str):
        try:
            number = float(value.strip())
        except ValueError:
            raise BadIssued(
                f"issued must be a number of Unix seconds, not {value[:40]!r}"
            ) from None
    elif isinstance(value, int | float):
        number = float(value)
    else:
        raise BadIssued(f"issued must be a number of Unix seconds, not {type(value).__name__}")
    if not math.isfinite(number) or number <= 0:
        raise BadIssued(f"issued must be a positive, finite number of Unix seconds, not {value!r}")
    return number


def stamp(issued: float | None, arrival: float) -> float:
    """When a command counts as issued, judged where it arrives: its own ``issued``, or its
    ``arrival`` if it has none; never later than its arrival (a clock ahead of ours makes a
    command no younger than it is when it reaches us).

    Raises:
        BadIssued: ``issued`` is more than ``MAX_AHEAD_S`` ahead of ``arrival`` (milliseconds
            sent for seconds, or a clock set wrong).
    """
    if issued is None:
        return arrival
    if issued > arrival + MAX_AHEAD_S:
        raise BadIssued(
            f"issued ({issued:.3f}) is {issued - arrival:.0f} s ahead of this clock: send Unix "
            "seconds (not milliseconds) of a clock set to the server's"
        )
    return min(issued, arrival)


def label(kind: str) -> str:
    """How the operator names a ``kind`` of command."""
    return LABELS.get(kind, kind.replace("_", " "))


def not_flown(what: str, verdict: Expired) -> str:
    """The operator's line for an expired command; ``what`` is its label or the sentence."""
    return (
        f"Not flown: '{what}' reached the drone {verdict.age_s:.1f} s after you gave it "
        f"(deadline {verdict.deadline_s:g} s)."
    )


def audit_outcome(verdict: Expired) -> str:
    """The audit log's outcome of an expired command: how late it was."""
    return (
        f"expired: delivered {verdict.age_s:.2f} s after it was issued, "
        f"{verdict.late_s:.2f} s past the {verdict.deadline_s:g} s deadline"
    )


class ClockOffset:
    """The offset of a remote clock (the console's) from ours, learnt from one-way stamps.

    Each sample is (remote time when sent, our time when received): remote − ours is the true
    offset less the message's transit time. The largest over the last ``window`` samples is
    the one that waited least, so a burst of late heartbeats (a stalled console, a stalled
    vehicle reading its backlog) does not make old commands look young; a clock step on
    either side is forgotten after ``window`` samples (30 s at the heartbeat's 10 Hz, longer
    than a vehicle waits for a silent console before it lands).
    """

    def __init__(self, window: int = 300) -> None:
        if window < 1:
            raise ValueError(f"window must be at least 1 sample, not {window}")
        self._samples: collections.deque[float] = collections.deque(maxlen=window)

    def sample(self, remote_t: float, local_t: float) -> None:
        """One stamp: sent at ``remote_t`` (remote clock), received at ``local_t`` (ours)."""
        if math.isfinite(remote_t) and math.isfinite(local_t):
            self._samples.append(remote_t - local_t)

    @property
    def offset_s(self) -> float | None:
        """Remote minus ours, in seconds (None before the first sample)."""
        return max(self._samples) if self._samples else None

    def to_local(self, remote_t: float) -> float:
        """A remote time on our clock (unchanged before the first sample)."""
        offset = self.offset_s
        return remote_t if offset is None else remote_t - offset


class ReportGate:
    """At most one report per ``key`` every ``interval_s`` (a jog sent at 10 Hz over a late
    link would otherwise say "Not flown" ten times a second)."""

    def __init__(self, interval_s: float = 2.0) -> None:
        self.interval_s = interval_s
        self._last: dict[str, float] = {}

    def allow(self, key: str, now: float) -> bool:
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            return False
        self._last[key] = now
        return True

    def reset(self, key: str) -> None:
        """A command of ``key`` was delivered: the next expiry is news again."""
        self._last.pop(key, None)
