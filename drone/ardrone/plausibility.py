"""Plausibility checks on navdata, which the AR.Drone sends without any authentication.

Anyone on the drone's Wi-Fi can send UDP to the client's navdata port with the drone's source
address and port. This module is the driver's second opinion, sans-I/O (packets and ``now`` in,
verdicts out), in three pure parts that :class:`NavdataPlausibility` puts together:

- :class:`SequenceGuard` — **which stream to follow.** The driver follows one numbering. A
  packet that continues it (at most ``max_seq_jump`` ahead) is taken. Any other packet — a
  duplicate, a lower number, a far jump — is dropped and counted; the stream is never left for
  another numbering while it is alive, so no forged packet, however many, can take its place or
  make it wait for a silence. A new numbering is followed only on the
  drone's own evidence: a restart (a lower number) only when its packets carry the drone's
  restart bits — NAVDATA_BOOTSTRAP (a booted drone before its configuration) or COM_WATCHDOG
  (ARDroneLib ``ardrone_navdata_client.c`` resets its sequence on this bit: "reset sequence
  number because of com watchdog") — *and* the old stream has gone silent for
  ``resync_quiet_s``; a jump ahead once the old stream has gone silent as long; and anything
  after a lost link (silence longer than the driver's link timeout: the driver calls
  :meth:`NavdataPlausibility.reset`). Each new numbering must be continued by ``resync_packets``
  packets. The bits alone prove nothing (a forger sets them too); the silence of the stream the
  driver follows is what a forger cannot produce.
- :class:`BatteryEnvelope` — **what the battery can do.** The reading is the filtered battery
  voltage as a percentage (``navdata_common.h``), so it follows the drain model of
  ``drone/sim/battery.py`` (the paper's) with margin, plus voltage sag under load. It keeps an
  interval for the resting level (the reading without sag): each reading says the resting level
  lies between the reading and the reading plus the largest sag the model allows at the recent
  load (``MAX_SAG_PCT_AT_HOVER`` at hover, ×1.5 in a full climb), ± ``battery_jitter_pct``;
  between readings the level falls by at most ``battery_max_drop_pct_s``·Δt and, in flight,
  never rises. A reading whose interval misses the predicted one is implausible in flight: it
  is not believed (the last plausible level is reported) and counts against the stream. A
  plausible but sudden drop (more than the jitter and the slope allow since the last report) is
  reported only once it has lasted ``battery_sag_confirm_s`` in flight (``battery_confirm_s``
  on the ground), as the highest level it held meanwhile: a transient sag at the start of a
  climb does not land the drone; a sag that stays does. ArduPilot does the same for voltage
  (``BATT_LOW_TIMER``, 10 s by default: "to cope with low voltage on long takeoffs",
  ``AP_BattMonitor_Params.cpp``); 3 s here because the AR.Drone's pack is small (~12 min) and
  3 s of flight cost at most 0.6 % at the model's fastest drain. On the ground with the motors
  off a drop is believed once it has lasted ``battery_confirm_s`` whatever its size: a low
  reading there only refuses a take-off, the safe side.

  What is safe for a real cliff. A drop the model allows and that lasts is believed, and a
  critical level then lands the drone as any critical level does (drone/supervisor/battery.py):
  a pack that sags to critical for seconds on end cannot be trusted with more flight; landing
  lowers the current (descending needs less thrust than hovering) and ends the flight where the
  drone is, before the voltage collapses further. Hovering to ask would keep drawing hover
  current from that pack. A drop beyond the model is different: no pack does that, so it is a
  sensor fault or another sender, and acting on it (landing wherever the drone is, blind) is
  what an attacker wants; the drone hovers on its own sensors and the operator decides, while
  the drone's firmware keeps watching its own battery (VBAT_LOW, state bit 15).
- :class:`DoubtTracker` — **whether to trust the stream.** ``doubt_packets`` suspicious packets
  within ``doubt_window_s`` make the stream doubted: packets off the numbering while the followed
  stream is alive (two senders on the drone's address), or battery readings implausible in
  flight; a reordered or corrupted packet now and then does not, nor do the packets of a
  restart that arrive while the old stream is silent. ``trust_again_s`` without any suspicious
  packet makes the stream trusted again.
  The driver reports both (``NavdataDoubt``/``NavdataTrusted``); the ANS then hovers the drone and
  asks the operator rather than act on the readings (``drone/supervisor/navdata.py``).

The numbers: a 1000 mAh AR.Drone 2.0 battery lasts ~12 minutes of flight (Parrot's figure), the
model's fastest drain is ≈ 0.21 %/s (full climb); 2 %/s is ten times that, room for the steep
end of a voltage-derived percentage and for simulated fast batteries (150 s packs drain
≤ 1 %/s), still far below a forged jump of 80 % in one packet. Demo navdata comes at ~15 Hz
(Developer Guide §7.1.2), full navdata at ~200 Hz: 1000 packets is 5 s to a minute, and
0.3 s is several packets of either, shorter than the driver's 0.5 s link timeout.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass

from drone.ardrone.navdata import CtrlState, DroneState, Navdata
from drone.sim.battery import CLIMB_EXTRA, MAX_SAG_PCT_AT_HOVER

# The state bits a drone sets when its navdata numbering restarts (module docstring).
RESTART_BITS = DroneState.NAVDATA_BOOTSTRAP | DroneState.COM_WATCHDOG
# Major control states with the motors turning (control_states.h).
MOTORS_ON_STATES = (
    CtrlState.TAKEOFF,
    CtrlState.FLYING,
    CtrlState.HOVERING,
    CtrlState.GOTOFIX,
    CtrlState.LANDING,
    CtrlState.LOOPING,
)
VZ_MAX_MM_S = 700.0  # control:control_vz_max indoor default (Developer Guide §8): full climb


@dataclass(frozen=True)
class PlausibilityConfig:
    """Thresholds of the checks (module docstring says where each number comes from)."""

    max_seq_jump: int = 1000
    resync_packets: int = 3
    resync_window: int = 50
    resync_quiet_s: float = 0.3
    doubt_packets: int = 3
    doubt_window_s: float = 1.0
    trust_again_s: float = 5.0
    battery_max_drop_pct_s: float = 2.0
    battery_jitter_pct: float = 3.0
    battery_max_sag_pct: float = MAX_SAG_PCT_AT_HOVER
    battery_sag_memory_s: float = 2.0  # the filtered reading lags the load this long
    battery_confirm_packets: int = 3
    battery_confirm_s: float = 1.0
    battery_sag_confirm_s: float = 3.0


@dataclass(frozen=True)
class Verdict:
    """What to do with one packet: ``navdata`` to use (None: drop it) and why, if anything is
    to be said; ``suspicious`` when the packet counts against the stream."""

    navdata: Navdata | None
    reason: str | None = None
    suspicious: bool = False


def motors_on(nav: Navdata) -> bool:
    """The packet says the motors turn (FLY bit, or a flying/taking-off/landing control state)."""
    if nav.state & DroneState.FLY:
        return True
    return nav.demo is not None and nav.demo.major in MOTORS_ON_STATES


def load_of(nav: Navdata) -> float:
    """Battery current relative to hover the packet implies (drone/sim/battery.py load_factor):
    0 motors off, 1 hover, up to 1 + CLIMB_EXTRA climbing at ``control_vz_max``."""
    if not motors_on(nav):
        return 0.0
    vz_down = nav.demo.vz_mm_s if nav.demo is not None else 0.0
    climb = -vz_down / VZ_MAX_MM_S if math.isfinite(vz_down) else 0.0
    return 1.0 + CLIMB_EXTRA * min(max(climb, 0.0), 1.0)


@dataclass(frozen=True)
class Dropped:
    """A packet off the followed numbering: why, and whether the followed stream was alive
    (a packet within ``resync_quiet_s`` of its last one): only those count against the stream,
    the others may be a restart the drone has not yet proven."""

    reason: str
    while_alive: bool


class SequenceGuard:
    """Which navdata numbering to follow (module docstring)."""

    def __init__(self, config: PlausibilityConfig) -> None:
        self.config = config
        self.last_seq: int | None = None
        self.last_at: float | None = None
        self.dropped = 0  # packets off the followed numbering, dropped
        self._cand_seq: int | None = None
        self._cand_count = 0

    def reset(self) -> None:
        """Follow whatever comes next (the link was lost: the old stream is long silent)."""
        self.last_seq = self.last_at = None
        self._cand_seq, self._cand_count = None, 0

    def check(self, nav: Navdata, now: float) -> Dropped | None:
        """None: follow this packet; else why it is dropped."""
        c, seq, last = self.config, nav.sequence, self.last_seq
        if last is None or self.last_at is None or 0 < seq - last <= c.max_seq_jump:
            self._follow(seq, now)
            return None
        if self._cand_seq is not None and 0 < seq - self._cand_seq <= c.resync_window:
            self._cand_count += 1
        else:
            self._cand_count = 1
        self._cand_seq = seq
        silent_s = now - self.last_at
        restart = seq <= last
        evidence = not restart or bool(nav.state & RESTART_BITS)
        if evidence and silent_s >= c.resync_quiet_s and self._cand_count >= c.resync_packets:
            self._follow(seq, now)
            return None
        self.dropped += 1
        alive = silent_s < c.resync_quiet_s
        if restart and last - seq < c.resync_window:
            return Dropped(
                f"navdata sequence {seq} after {last}: stale or repeated; dropped", alive
            )
        if restart:
            why = "without the drone's restart bits" if not evidence else "while it still streams"
            return Dropped(
                f"navdata sequence {seq} after {last}: a restart {why}; dropped, the drone's "
                "stream is kept",
                alive,
            )
        return Dropped(
            f"navdata sequence jumped from {last} to {seq}; dropped until a silence of the "
            "followed stream and consistent packets confirm it",
            alive,
        )

    def _follow(self, seq: int, now: float) -> None:
        self.last_seq, self.last_at = seq, now
        self._cand_seq, self._cand_count = None, 0


@dataclass(frozen=True)
class BatteryVerdict:
    """The level to report (%), and whether the reading was implausible, with why."""

    report_pct: int
    implausible: bool = False
    reason: str | None = None


class BatteryEnvelope:
    """Whether battery readings fit the drain-and-sag model and each other (module docstring)."""

    def __init__(self, config: PlausibilityConfig) -> None:
        self.config = config
        self.lo = 0.0  # lowest resting level the readings so far allow, %
        self.hi = 100.0  # highest, %
        self._t = 0.0  # when lo/hi were last updated
        self.reported: int | None = None  # last level reported (believed), %
        self._reported_at = 0.0
        self._loads: deque[tuple[float, float]] = deque()  # (t, load) over the sag memory
        self._pending_since: float | None = None  # a sudden drop waiting to last
        self._pending_max = 0
        self._pending_count = 0

    def check(self, level: int, now: float, load: float, flying: bool) -> BatteryVerdict:
        """The verdict on one reading ``level`` (%) at ``now``, at ``load`` (current relative to
        hover), ``flying`` when the motors turn."""
        c, j = self.config, self.config.battery_jitter_pct
        sag = c.battery_max_sag_pct * self._recent_load(load, now)
        if not 0 <= level <= 100:
            held = self.reported if self.reported is not None else min(max(level, 0), 100)
            return BatteryVerdict(
                held, implausible=True, reason=f"battery reading {level} % is not a percentage"
            )
        lo_r, hi_r = level - j, level + sag + j  # the resting level this reading allows
        if self.reported is None:
            self._bound(lo_r, hi_r, now)
            self._report(level, now)
            return BatteryVerdict(level)
        lo_p = self.lo - c.battery_max_drop_pct_s * max(0.0, now - self._t)
        hi_p = self.hi if flying else 100.0  # landed: the voltage recovers, a pack may be swapped
        if hi_r < lo_p or lo_r > hi_p:
            if flying:
                return BatteryVerdict(
                    self.reported,
                    implausible=True,
                    reason=(
                        f"battery reading {level} % that no discharge or sag explains after "
                        f"{self.reported} %; keeping {self.reported} %"
                    ),
                )
            fits = False
        else:
            self._bound(max(lo_p, lo_r), min(hi_p, hi_r), now)
            fits = True
        allowed = j + c.battery_max_drop_pct_s * max(0.0, now - self._reported_at)
        if level >= self.reported - allowed:
            self._pending_since = None
            if fits:
                self._report(level, now)
                return BatteryVerdict(level)
            # landed, above the last report but outside the bounds: start them afresh
            self._bound(lo_r, hi_r, now)
            self._report(level, now)
            return BatteryVerdict(level)
        if self._pending_since is None:
            self._pending_since, self._pending_max, self._pending_count = now, level, 1
        else:
            self._pending_max = max(self._pending_max, level)
            self._pending_count += 1
        need_s = c.battery_sag_confirm_s if flying else c.battery_confirm_s
        if self._pending_count >= c.battery_confirm_packets and now - self._pending_since >= need_s:
            held = self._pending_max
            before = self.reported
            self._pending_since = None
            if not fits:
                self._bound(held - j, held + sag + j, now)
            self._report(held, now)
            why = "under load (voltage sag)" if flying else "on the ground"
            return BatteryVerdict(
                held, reason=f"battery fell from {before} % to {held} % {why} and stayed there"
            )
        return BatteryVerdict(self.reported)

    def _recent_load(self, load: float, now: float) -> float:
        loads = self._loads
        loads.append((now, load))
        while loads and loads[0][0] < now - self.config.battery_sag_memory_s:
            loads.popleft()
        return max(v for _, v in loads)

    def _bound(self, lo: float, hi: float, now: float) -> None:
        self.lo, self.hi, self._t = lo, hi, now

    def _report(self, level: int, now: float) -> None:
        self.reported, self._reported_at = level, now


class DoubtTracker:
    """Whether the stream is doubted: enough suspicious packets lately (module docstring)."""

    def __init__(self, config: PlausibilityConfig) -> None:
        self.config = config
        self.reason = ""  # why the stream is doubted; "" while it is trusted
        self._times: deque[float] = deque()
        self._last = -math.inf

    def note(self, reason: str, now: float) -> None:
        """One suspicious packet at ``now``."""
        self._last = now
        times = self._times
        times.append(now)
        while times and times[0] <= now - self.config.doubt_window_s:
            times.popleft()
        if not self.reason and len(times) >= self.config.doubt_packets:
            self.reason = reason

    def poll(self, now: float) -> None:
        """Trust the stream again after ``trust_again_s`` without a suspicious packet."""
        if self.reason and now - self._last >= self.config.trust_again_s:
            self.reason = ""
            self._times.clear()


class NavdataPlausibility:
    """Sequence, battery and trust checks for one drone's navdata stream (module docstring)."""

    def __init__(self, config: PlausibilityConfig | None = None) -> None:
        self.config = config or PlausibilityConfig()
        self.sequence = SequenceGuard(self.config)
        self.battery = BatteryEnvelope(self.config)
        self.trust = DoubtTracker(self.config)
        self.suspicious = 0  # packets dropped or with an implausible battery, so far

    @property
    def dropped(self) -> int:
        """Packets dropped because they did not follow the drone's numbering."""
        return self.sequence.dropped

    @property
    def doubt(self) -> str:
        """Why the stream is doubted, or "" while it is trusted."""
        return self.trust.reason

    def reset(self) -> None:
        """The link was lost: follow the next stream whatever its numbering. The battery's
        history stays: it is the same battery."""
        self.sequence.reset()

    def poll(self, now: float) -> None:
        """Time passing alone may restore trust; call it on every turn of the driver."""
        self.trust.poll(now)

    def check(self, nav: Navdata, now: float) -> Verdict:
        """The verdict on one decoded packet from the drone's address and port."""
        self.trust.poll(now)
        dropped = self.sequence.check(nav, now)
        if dropped is not None:
            if dropped.while_alive:
                self._suspect("packets that do not follow the drone's navdata sequence", now)
            return Verdict(None, dropped.reason, suspicious=dropped.while_alive)
        demo = nav.demo
        if demo is None:
            return Verdict(nav)
        b = self.battery.check(int(demo.battery_pct), now, load_of(nav), motors_on(nav))
        if b.implausible:
            self._suspect("battery readings that no discharge or sag explains", now)
        if b.report_pct != demo.battery_pct:
            nav = dataclasses.replace(nav, demo=dataclasses.replace(demo, battery_pct=b.report_pct))
        return Verdict(nav, b.reason, suspicious=b.implausible)

    def _suspect(self, reason: str, now: float) -> None:
        self.suspicious += 1
        self.trust.note(reason, now)
