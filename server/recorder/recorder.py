"""The flight recorder: a graph tap feeding a writer thread that writes MCAP files.

Cost on the flight path: the tap (``Graph.add_tap``) runs in the publishing thread and only
appends ``(time, topic, type, message)`` to a deque; serialising, compressing (zstd) and writing
happen in the recorder's own thread, which wakes every ``poll_s``. Messages are never copied:
graph messages are not changed after they are published. If the writer falls behind, the
deque drops its oldest entries (counted in ``dropped``) rather than grow without bound.

Failure: any ``OSError`` while writing (``ENOSPC`` — disk full —, a removed directory, …) or
a recording that alone exceeds the disk budget stops the recording: the file is closed where it
is (it reads back up to its last finished chunk), an alert goes to ``/console/reply`` and the
log, and flying goes on untouched. The next flight session tries again.
"""

from __future__ import annotations

import collections
import errno
import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from server import msgs
from server.graph import Graph
from server.recorder.errors import CorruptRecording
from server.recorder.index import FlightIndex, FlightInfo, drones_of, iso
from server.recorder.mcapfile import FlightFile, Opener, open_private
from server.recorder.sessions import Change, FlightDetector

log = logging.getLogger("uav_console.recorder")

Item = tuple[int, str, str, dict[str, Any]]  # (log time ns, topic, type, message)
# Messages written between two voluntary GIL releases (a camera frame is ~0.1 ms of work), so
# the writer never holds the interpreter for long while a control tick waits.
YIELD_EVERY = 8
REPLY_TOPIC = "/console/reply"
REPLY_TYPE = "uav_console/Reply"


@dataclass(frozen=True)
class RecorderConfig:
    directory: Path
    budget_bytes: int = 2 * 1024**3
    chunk_s: float = 2.0  # a finished chunk at least this often: what a crash can lose
    chunk_size: int = 1024 * 1024  # or sooner, when a chunk reaches this many bytes
    preroll_s: float = 10.0  # kept before a session starts and written into it
    idle_s: float = 30.0  # on the ground with no command this long: the session ends
    poll_s: float = 0.05
    max_pending: int = 100_000
    world: str = ""  # the world flown in (replay loads it for the map)


class Recorder:
    """Records every graph topic while a flight session lasts (see ``sessions``)."""

    def __init__(
        self,
        graph: Graph,
        config: RecorderConfig,
        *,
        drones: Callable[[], Iterable[str]] = lambda: (),
        clock: Callable[[], float] = time.time,
        opener: Opener = open_private,
        stamp_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        self.graph = graph
        self.config = config
        self.index = FlightIndex(config.directory, config.budget_bytes)
        self._drones = drones
        self._clock = clock
        self._opener = opener
        self._stamp_ns = stamp_ns  # the log time of each message (wall clock, ns)
        self._inbox: collections.deque[Item] = collections.deque(maxlen=config.max_pending)
        self._preroll: collections.deque[Item] = collections.deque()
        self._latest: dict[str, Item] = {}
        self._detector = FlightDetector(config.idle_s)
        self._lock = threading.Lock()
        self._touched: float | None = None
        self._current_id: str | None = None
        self._file: FlightFile | None = None
        self._failed = False  # this session's recording stopped on an error
        self._last_flush = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._remove_tap: Callable[[], None] | None = None
        self.dropped = 0
        self.last_error: str | None = None

    # -- lifecycle -----------------------------------------------------------------------
    def start(self, *, background: bool = True) -> None:
        """Repair what a crash left, tap the graph and start the writer thread.

        ``background=False`` starts no thread: the caller drives :meth:`step` (tests, lockstep).
        """
        self.index.ensure_dir()
        self._repair_crashed()
        self._remove_tap = self.graph.add_tap(self._tap)
        if background:
            self._thread = threading.Thread(target=self._run, name="flight-recorder", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop tapping, write what is pending and finish the current recording."""
        if self._remove_tap is not None:
            self._remove_tap()
            self._remove_tap = None
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
            self._thread = None
        self.step(self._clock())
        self._close(self._clock())

    def _repair_crashed(self) -> None:
        for path in self.index.files():
            try:
                if self.index.repair(path):
                    log.warning("recording %s was cut short (crash?); repaired", path.name)
            except (CorruptRecording, OSError) as exc:
                log.warning("recording %s cannot be repaired: %s", path.name, exc)

    # -- the tap (publishing threads) ----------------------------------------------------
    def _tap(self, topic: str, type_name: str, msg: dict[str, Any]) -> None:
        inbox = self._inbox
        if len(inbox) == inbox.maxlen:
            self.dropped += 1
        inbox.append((self._stamp_ns(), topic, type_name, msg))

    # -- queries (any thread) ------------------------------------------------------------
    @property
    def current_id(self) -> str | None:
        return self._current_id

    def touch(self) -> str:
        """An operator command: start a session if none is open; the recording's id."""
        now = self._clock()
        with self._lock:
            self._touched = now
            if self._current_id is None:
                self._current_id = self.index.new_id(now)
            return self._current_id

    def current_info(self) -> FlightInfo | None:
        f, fid = self._file, self._current_id
        if f is None or fid is None:
            return None
        drones = sorted(set(self._drones()) | self._detector.drones)
        return FlightInfo(fid, iso(f.started_ns), None, drones, f.bytes, f.messages)

    def flights(self) -> list[FlightInfo]:
        return self.index.listing(self.current_info())

    def flush_now(self) -> None:
        """Have the writer take in and flush what is pending (for tests and shutdown)."""
        with self._lock:
            self._step_locked(self._clock(), force_flush=True)

    # -- the writer thread ---------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.wait(self.config.poll_s):
            try:
                self.step(self._clock())
            except Exception:  # the recorder must never take the server down
                log.exception("flight recorder step failed")

    def step(self, now: float | None = None) -> None:
        """Take in what the tap queued, open/close sessions and flush when due."""
        with self._lock:
            self._step_locked(self._clock() if now is None else now)

    def _step_locked(self, now: float, *, force_flush: bool = False) -> None:
        inbox = self._inbox
        taken = 0
        while inbox:
            item = inbox.popleft()
            taken += 1
            if taken % YIELD_EVERY == 0:
                time.sleep(0)  # let the 100 Hz control thread have the GIL between messages
            _, topic, type_name, msg = item
            self._detector.observe(topic, type_name, msg, now)
            self._latest[topic] = item
            if self._file is not None:
                self._write(item)
            elif not self._failed:
                self._preroll.append(item)
        horizon = self._stamp_ns() - int(self.config.preroll_s * 1e9)
        while self._preroll and self._preroll[0][0] < horizon:
            self._preroll.popleft()
        if self._touched is not None:
            self._detector.touch(self._touched)
            self._touched = None
        change = self._detector.poll(now)
        if change is Change.START:
            self._open(now)
        elif change is Change.END:
            self._close(now)
        due = force_flush or now - self._last_flush >= self.config.chunk_s
        if self._file is not None and due:
            self._last_flush = now
            try:
                self._file.flush()
            except OSError as exc:
                self._fail(exc)
                return
            self._check_budget()

    def _open(self, now: float) -> None:
        if self._current_id is None:
            self._current_id = self.index.new_id(now)
        self._failed = False
        fid = self._current_id
        path = self.index.directory / f"{fid}.mcap"
        try:
            self.index.ensure_dir()
            self._file = FlightFile(
                path,
                fid,
                self._stamp_ns(),
                chunk_size=self.config.chunk_size,
                opener=self._opener,
                metadata={"world": self.config.world, "preroll_s": str(self.config.preroll_s)},
            )
        except OSError as exc:
            self._file = None
            self._fail(exc)
            return
        self._last_flush = now
        log.info("flight session %s: recording to %s", fid, path)
        # Latest message of every topic not in the pre-roll (state a replay starts from),
        # then the pre-roll itself, in time order. The state is logged at the recording's
        # first instant, not when it was published (a dialog state latched at start-up, 12
        # minutes before the take-off, would stretch the flight's timeline by 12 minutes);
        # the messages keep their own header stamps.
        pre = list(self._preroll)
        self._preroll.clear()
        in_pre = {i[1] for i in pre}
        t0 = min(pre[0][0], self._file.started_ns) if pre else self._file.started_ns
        snapshot = sorted((i for t, i in self._latest.items() if t not in in_pre), key=_t)
        state: list[Item] = [(t0, topic, typ, msg) for _, topic, typ, msg in snapshot]
        for item in state + pre:
            if self._file is None:
                break
            self._write(item)
        self._check_budget()

    def _write(self, item: Item) -> None:
        assert self._file is not None
        t, topic, type_name, msg = item
        try:
            self._file.write(topic, type_name, t, msg)
        except OSError as exc:
            self._fail(exc)

    def _close(self, now: float) -> None:
        f = self._file
        fid = self._current_id
        self._file = None
        self._current_id = None
        self._failed = False
        if f is None:
            return
        drones = sorted(
            set(self._drones()) | self._detector.drones | set(drones_of(list(f.topics)))
        )
        try:
            f.finish(self._stamp_ns(), drones)
            log.info("flight session %s ended: %d messages, %d bytes", fid, f.messages, f.bytes)
        except OSError as exc:
            f.abandon()
            self._alert(f"flight recording {fid} could not be finished: {_why(exc)}")

    def _check_budget(self) -> None:
        f = self._file
        if f is None:
            return
        try:
            deleted, over = self.index.over_budget(self._current_id, f.bytes)
        except OSError as exc:
            log.warning("disk budget check failed: %s", exc)
            return
        for fid in deleted:
            log.info("disk budget: deleted the oldest recording %s", fid)
        if over:
            self._stop_recording(
                f"flight recording {self._current_id} stopped: it reached the disk budget of "
                f"{self.config.budget_bytes // (1024 * 1024)} MiB; flying goes on",
                finish=True,
            )

    def _fail(self, exc: OSError) -> None:
        self._stop_recording(
            f"flight recording {self._current_id} stopped: {_why(exc)}; flying goes on"
        )

    def _stop_recording(self, text: str, *, finish: bool = False) -> None:
        """Stop this session's recording and say why; ``finish``: the file can still be
        written (the budget, not a write error), so it gets its summary and reads back whole."""
        f = self._file
        self._file = None
        self._failed = True
        if f is not None and finish:
            try:
                f.finish(self._stamp_ns(), sorted(set(self._drones()) | self._detector.drones))
            except OSError:
                f.abandon()
        elif f is not None:
            f.abandon()
        self._preroll.clear()
        self.last_error = text
        self._alert(text)

    def _alert(self, text: str) -> None:
        log.error(text)
        reply = {
            "header": msgs.header("map"),
            "text": text,
            "level": "alert",
            "speak": False,
            "utterance": "",
            "commands": "[]",
        }
        try:
            self.graph.publish(REPLY_TOPIC, reply, type=REPLY_TYPE)
        except Exception:  # an alert that cannot be shown must not stop the recorder
            log.exception("recorder alert could not be published")


def _t(item: Item) -> int:
    return item[0]


def _why(exc: OSError) -> str:
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"the disk is full ({exc.strerror})"
    return f"cannot write the recording ({exc})"


def config_from_settings(settings: Any) -> RecorderConfig:
    """The recorder's configuration from ``server.settings.Settings``."""
    directory = settings.recordings_dir or settings.data_dir / "flights"
    return RecorderConfig(
        directory=Path(directory),
        budget_bytes=int(settings.recorder_budget_mb * 1024 * 1024),
        chunk_s=settings.recorder_chunk_s,
        idle_s=settings.recorder_idle_s,
        preroll_s=settings.recorder_preroll_s,
        world=str(settings.world),
    )
