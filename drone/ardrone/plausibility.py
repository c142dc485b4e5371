"""Plausibility checks on navdata, which the AR.Drone sends without any authentication.

Anyone on the drone's Wi-Fi can send UDP to the client's navdata port with the drone's source
address. Issue 14 found that one forged packet (battery 3 %) made the console land a drone at
85 %, and that its sequence number (far ahead) made the driver drop every real packet after it
as stale. This module is the driver's second opinion, sans-I/O (packets and ``now`` in,
verdicts out):

- **Sequence jumps.** A packet whose sequence is more than ``max_seq_jump`` ahead of the last
  accepted one is held back. The new numbering is believed only after ``resync_packets``
  consecutive packets continue it (each within ``resync_window`` of the previous) *and* the old
  numbering has gone quiet for ``resync_quiet_s``: a rebooted drone stops its old stream; a
  forger cannot silence the real one. (A restart at sequence 1 and a lost link are handled by
  the driver as before.)
- **Battery slope.** The battery cannot fall faster than ``battery_max_drop_pct_s`` (+ a
  ``battery_jitter_pct`` allowance). A steeper drop is not believed until ``battery_confirm_
  packets`` consecutive packets agree on the new level (within the jitter) over at least
  ``battery_confirm_s``; a plausible packet in between (the real drone) cancels it. Meanwhile
  the last plausible level is reported, so a safety landing only ever follows consistent
  packets.

The numbers: a 1000 mAh AR.Drone 2.0 battery lasts ~12 minutes of flight (Parrot's figure),
~0.14 %/s on average; 2 %/s is 14× that, well beyond any real discharge slope while still
two orders of magnitude below a forged jump of 80 % in one packet. Demo navdata comes at
~15 Hz (Developer Guide §7.1.2), full navdata at ~200 Hz: 1000 packets is 5 s to a minute.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from drone.ardrone.navdata import Navdata


@dataclass(frozen=True)
class PlausibilityConfig:
    max_seq_jump: int = 1000
    resync_packets: int = 3
    resync_window: int = 50
    resync_quiet_s: float = 0.3
    battery_max_drop_pct_s: float = 2.0
    battery_jitter_pct: float = 3.0
    battery_confirm_packets: int = 3
    battery_confirm_s: float = 1.0


@dataclass(frozen=True)
class Verdict:
    """What to do with one packet: ``navdata`` to use (None: drop it) and why, if suspicious."""

    navdata: Navdata | None
    reason: str | None = None


class NavdataPlausibility:
    """Sequence and battery checks for one drone's navdata stream (see the module docstring)."""

    def __init__(self, config: PlausibilityConfig | None = None) -> None:
        self.config = config or PlausibilityConfig()
        self.last_seq: int | None = None
        self.last_seq_at: float | None = None
        self._cand_seq: int | None = None
        self._cand_count = 0
        self.battery_ok: int | None = None  # last plausible battery level, %
        self._battery_ok_at = 0.0
        self._pending_battery: int | None = None
        self._pending_since = 0.0
        self._pending_count = 0
        self.suspicious = 0  # packets held or corrected so far

    def reset(self) -> None:
        """Forget the stream (the link was lost, or the drone restarted at sequence 1)."""
        self.last_seq = self.last_seq_at = None
        self._cand_seq, self._cand_count = None, 0

    def accept_sequence(self, seq: int, now: float) -> None:
        """The driver accepted ``seq`` by its own rules (restart, link restored)."""
        self.last_seq, self.last_seq_at = seq, now
        self._cand_seq, self._cand_count = None, 0

    def check(self, nav: Navdata, now: float) -> Verdict:
        """The verdict on one decoded packet the driver would otherwise accept."""
        c = self.config
        seq = nav.sequence
        if (
            self.last_seq is not None
            and self.last_seq_at is not None
            and seq - self.last_seq > c.max_seq_jump
        ):
            if self._cand_seq is not None and 0 < seq - self._cand_seq <= c.resync_window:
                self._cand_count += 1
            else:
                self._cand_count = 1
            self._cand_seq = seq
            quiet = now - self.last_seq_at >= c.resync_quiet_s
            if not (self._cand_count >= c.resync_packets and quiet):
                self.suspicious += 1
                return Verdict(
                    None,
                    f"navdata sequence jumped from {self.last_seq} to {seq} while the stream "
                    "is alive; held until it is confirmed",
                )
        self.accept_sequence(seq, now)
        return self._check_battery(nav, now)

    def _check_battery(self, nav: Navdata, now: float) -> Verdict:
        c = self.config
        demo = nav.demo
        if demo is None:
            return Verdict(nav)
        level = int(demo.battery_pct)
        if self.battery_ok is None:
            self._believe(level, now)
            return Verdict(nav)
        allowed = c.battery_jitter_pct + c.battery_max_drop_pct_s * (now - self._battery_ok_at)
        if level >= self.battery_ok - allowed:
            self._believe(level, now)
            return Verdict(nav)
        pending = self._pending_battery
        if pending is not None and abs(level - pending) <= c.battery_jitter_pct:
            self._pending_count += 1
        else:
            self._pending_battery, self._pending_since, self._pending_count = level, now, 1
        if (
            self._pending_count >= c.battery_confirm_packets
            and now - self._pending_since >= c.battery_confirm_s
        ):
            self._believe(level, now)
            return Verdict(nav, f"battery fell to {level} % (confirmed by consistent packets)")
        self.suspicious += 1
        held = dataclasses.replace(nav, demo=dataclasses.replace(demo, battery_pct=self.battery_ok))
        return Verdict(
            held,
            f"implausible battery drop {self.battery_ok} % -> {level} %; "
            f"keeping {self.battery_ok} % until consistent packets confirm it",
        )

    def _believe(self, level: int, now: float) -> None:
        self.battery_ok, self._battery_ok_at = level, now
        self._pending_battery, self._pending_count = None, 0
