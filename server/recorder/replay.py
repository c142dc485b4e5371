"""A recorded flight played back onto a graph: the timeline (sans-I/O) and its asyncio driver.

:class:`Timeline` holds the decoded messages in time order and a playback position; it is
told the wall-clock time (``now``) and returns what to publish, so seeking and speed are
plain arithmetic that tests drive without sleeping. :class:`Player` runs it on the event loop
and publishes onto the graph, where the rosbridge endpoint, the REST API and the console see the
recorded topics exactly as they saw them live.

Seeking publishes, for every topic, the last message at or before the new position (then
playback goes on from there), so the console shows the state at that moment at once: task,
dialog state, the last camera frame, the drone's pose.
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from server.graph import Graph
from server.recorder.mcapfile import Recording, read_recording

log = logging.getLogger("uav_console.replay")
OWNER = "replay"
DEFAULT_PREROLL_S = 10.0  # RecorderConfig.preroll_s of recordings that do not name theirs


@dataclass(frozen=True)
class Played:
    t_ns: int
    topic: str
    type: str
    msg: dict[str, Any]


class Timeline:
    """Playback position over a recording's messages (times in ns of the recording)."""

    def __init__(
        self, messages: list[Played], speed: float = 1.0, *, start_ns: int | None = None
    ) -> None:
        """``start_ns``: where the timeline starts when that is after the first message (the
        flight's start, :func:`flight_start_ns`); earlier messages are the state at the
        start, published at once."""
        if speed <= 0:
            raise ValueError("speed must be positive")
        self.messages = sorted(messages, key=lambda p: p.t_ns)
        self._times = [p.t_ns for p in self.messages]
        self.start_ns = self._times[0] if self._times else 0
        self.end_ns = self._times[-1] if self._times else 0
        if start_ns is not None:
            self.start_ns = min(max(self.start_ns, start_ns), self.end_ns)
        self.speed = speed
        self.playing = False
        self.position_ns = self.start_ns
        self._next = 0  # index of the next message to publish
        self._anchor: tuple[float, int] | None = None  # (wall time, position) when play began

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def update(self, now: float) -> None:
        """Bring ``position_ns`` up to ``now`` (what is due stays due for :meth:`due`)."""
        self._advance(now)

    def _advance(self, now: float) -> None:
        if self.playing and self._anchor is not None:
            wall0, pos0 = self._anchor
            self.position_ns = min(self.end_ns, pos0 + int((now - wall0) * self.speed * 1e9))

    def play(self, now: float) -> list[Played]:
        """Start (or go on) playing; at the end it starts over. Returns what to publish."""
        out: list[Played] = []
        if self.position_ns >= self.end_ns:
            out = self.seek(self.start_ns, now)
        self._advance(now)
        self.playing = True
        self._anchor = (now, self.position_ns)
        return out + self.due(now)

    def pause(self, now: float) -> None:
        self._advance(now)
        self.playing = False
        self._anchor = None

    def set_speed(self, speed: float, now: float) -> None:
        if speed <= 0:
            raise ValueError("speed must be positive")
        self._advance(now)
        self.speed = speed
        if self.playing:
            self._anchor = (now, self.position_ns)

    def seek(self, position_ns: int, now: float) -> list[Played]:
        """Jump to ``position_ns`` (clamped); the last message of every topic up to it."""
        self.position_ns = max(self.start_ns, min(self.end_ns, position_ns))
        if self.playing:
            self._anchor = (now, self.position_ns)
        self._next = bisect.bisect_right(self._times, self.position_ns)
        latest: dict[str, Played] = {}
        for p in self.messages[: self._next]:
            latest[p.topic] = p
        return sorted(latest.values(), key=lambda p: p.t_ns)

    def due(self, now: float) -> list[Played]:
        """Messages whose time has come at ``now``; playback stops at the end."""
        self._advance(now)
        end = bisect.bisect_right(self._times, self.position_ns, lo=self._next)
        out = self.messages[self._next : end]
        self._next = end
        if self.playing and self.position_ns >= self.end_ns:
            self.playing = False
            self._anchor = None
        return out

    def next_due_in(self, now: float) -> float | None:
        """Seconds of wall time until the next message (None: nothing to wait for)."""
        if not self.playing or self._next >= len(self.messages):
            return None
        self._advance(now)
        return max(0.0, (self._times[self._next] - self.position_ns) / 1e9 / self.speed)

    def status(self) -> dict[str, Any]:
        return {
            "playing": self.playing,
            "speed": self.speed,
            "position_s": (self.position_ns - self.start_ns) / 1e9,
            "duration_s": self.duration_s,
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "messages": len(self.messages),
        }


def flight_start_ns(recording: Recording) -> int | None:
    """Where the flight's timeline starts: its start less the recorder's pre-roll.

    The recorder logs the state it starts from at that instant; recordings made before it
    did logged it when it was published, maybe minutes before the flight, so the timeline is
    cut here rather than at the first message. None when the file does not say.
    """
    meta = recording.metadata.get("flight", {})
    try:
        started = int(meta["started_ns"])
        preroll_s = float(meta.get("preroll_s", DEFAULT_PREROLL_S))
    except (KeyError, ValueError):
        return None
    return started - int(max(0.0, preroll_s) * 1e9)


def load(path: Path, *, recover: bool = False) -> tuple[Recording, list[Played]]:
    """Read and decode a recording for replay.

    Raises:
        CorruptRecording: not a readable MCAP file (or, without ``recover``, one cut short);
            the message names the byte offset.
    """
    rec = read_recording(path, strict=not recover)
    played = [Played(t, ch.topic, ch.type, msg) for ch, t, msg in rec.decoded()]
    return rec, played


class Player:
    """Publishes a :class:`Timeline` onto a graph in (scaled) real time."""

    def __init__(
        self, graph: Graph, timeline: Timeline, clock: Callable[[], float] | None = None
    ) -> None:
        self.graph = graph
        self.timeline = timeline
        self._clock = clock
        self._wake = asyncio.Event()
        self.latest: dict[str, dict[str, Any]] = {}
        self.latest_ns: dict[str, int] = {}  # when (recording time) each was logged

    def now(self) -> float:
        return self._clock() if self._clock is not None else time.monotonic()

    def advertise(self) -> None:
        """Advertise the recorded topics, latched: a client that subscribes (or a page that
        loads) while the replay is paused or between two messages gets the state at once."""
        for p in self.timeline.messages:
            if self.graph.topic_type(p.topic) in (None, p.type):
                self.graph.advertise(p.topic, p.type, latch=True, owner=OWNER)

    def publish(self, items: list[Played]) -> None:
        for p in items:
            self.latest[p.topic] = p.msg
            self.latest_ns[p.topic] = p.t_ns
            try:
                self.graph.publish(p.topic, p.msg, type=p.type)
            except Exception as exc:  # a topic the live graph types differently
                log.warning("replay: cannot publish %s: %s", p.topic, exc)

    # -- controls (called on the loop thread by the REST router) --------------------------
    def play(self) -> None:
        self.publish(self.timeline.play(self.now()))
        self._wake.set()

    def pause(self) -> None:
        self.timeline.pause(self.now())
        self._wake.set()

    def seek(self, position_s: float) -> None:
        t = self.timeline.start_ns + int(position_s * 1e9)
        self.publish(self.timeline.seek(t, self.now()))
        self._wake.set()

    def set_speed(self, speed: float) -> None:
        self.timeline.set_speed(speed, self.now())
        self._wake.set()

    async def run(self) -> None:
        """Play until cancelled (paused at the end; the controls start it again)."""
        while True:
            self.publish(self.timeline.due(self.now()))
            wait = self.timeline.next_due_in(self.now())
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), 3600.0 if wait is None else wait)
