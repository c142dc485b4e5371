"""AR.Drone 2.0 battery model: state of charge in percent, drained by flight, and the reading the
drone reports, which sags under load.

Drain (the paper's model): the stock 1000 mAh pack gives about 12 minutes of flight (Parrot's
specification for the AR.Drone 2.0), so hovering drains 100 % in 720 s; climbing costs more
thrust, modelled as up to +50 % drain at full ``control_vz_max``. Landed with motors off the
electronics draw little. The drone sets the VBAT_LOW state bit below 20 % and refuses to take off
while it is set (firmware behaviour reported in the Developer Guide §7.1.2 state bits and by
ARDroneLib's ``ARDRONE_VBAT_LOW``).

Sag: the demo option's ``vbat_flying_percentage`` is derived from the filtered battery voltage
(ARDroneLib ``navdata_common.h``: "battery voltage filtered (mV)"), and a pack's voltage under
load is its open-circuit voltage less current × internal resistance (the Thevenin equivalent
circuit of a cell). So the reading falls at once when the load rises and recovers when it falls.
The load is the current relative to hover: 0 with the motors off, 1 at hover, up to
1 + ``CLIMB_EXTRA`` at full climb (the same factor as the drain). ``sag_pct_at_hover`` is the
extra sag of this pack at hover current, beyond what the firmware's flying percentage already
allows for; 0 for the healthy pack of the paper's model. :data:`MAX_SAG_PCT_AT_HOVER` is the
largest the model allows: a worn pack whose internal resistance has grown by ~90 mΩ sags a further
~0.45 V at the ~5 A hover current (1000 mAh in 12 min), 15 % of the ~3 V span (9.6–12.6 V, three
cells at 3.2–4.2 V) that the percentage covers.
"""

from __future__ import annotations

from dataclasses import dataclass

LOW_PCT = 20.0  # VBAT_LOW bit below this
FLIGHT_TIME_S = 720.0  # ~12 min from 100 % at hover
IDLE_DRAIN_PCT_S = 0.005  # motors off (Wi-Fi, cameras, CPU)
CLIMB_EXTRA = 0.5  # extra drain fraction at full climb rate
MAX_SAG_PCT_AT_HOVER = 15.0  # a worn pack's sag at hover load, percentage points (see above)
MAX_DRAIN_PCT_S = 100.0 / FLIGHT_TIME_S * (1.0 + CLIMB_EXTRA)  # full climb: ≈ 0.21 %/s
# The fastest injected leak: with the fastest drain it stays under the 2 %/s a real pack's
# reading may fall (drone/ardrone/plausibility.py), so the drone believes it and acts.
MAX_LEAK_PCT_S = 1.5


def load_factor(motors_on: bool, climb_fraction: float = 0.0) -> float:
    """Battery current relative to hover: 0 motors off, 1 hover, 1 + CLIMB_EXTRA at full climb."""
    if not motors_on:
        return 0.0
    return 1.0 + CLIMB_EXTRA * min(max(climb_fraction, 0.0), 1.0)


@dataclass
class Battery:
    """Mutable state of charge; ``step`` is called by the physics at every tick."""

    pct: float = 100.0
    flight_time_s: float = FLIGHT_TIME_S
    low_pct: float = LOW_PCT
    sag_pct_at_hover: float = 0.0  # extra sag of this pack at hover load (0: healthy)
    load: float = 0.0  # current relative to hover at the last step (see load_factor)
    leak_pct_s: float = 0.0  # extra drain of a failing pack (fault injection), %/s

    def step(self, dt: float, motors_on: bool, climb_fraction: float = 0.0) -> None:
        """Drain for ``dt`` seconds; ``climb_fraction`` is vz_up / control_vz_max (clipped 0..1)."""
        self.load = load_factor(motors_on, climb_fraction)
        rate = 100.0 / self.flight_time_s * self.load if motors_on else IDLE_DRAIN_PCT_S
        self.pct = max(0.0, self.pct - (rate + self.leak_pct_s) * dt)

    @property
    def reading_pct(self) -> float:
        """What the drone reports: the charge less the voltage sag at the present load."""
        return max(0.0, self.pct - self.sag_pct_at_hover * self.load)

    @property
    def low(self) -> bool:
        return self.pct < self.low_pct

    @property
    def can_take_off(self) -> bool:
        return not self.low

    @property
    def empty(self) -> bool:
        return self.pct <= 0.0

    def charge(self, pct: float) -> None:
        """Add ``pct`` percent, up to 100: a world's charging pad (``Station.charge_pct_s``)
        charging a drone landed on it. The drain in flight is the model's, unchanged."""
        if pct > 0.0:
            self.pct = min(100.0, self.pct + pct)

    def drain_to(self, pct: float) -> None:
        """Set the charge (fault injection); clipped to 0..100."""
        self.pct = min(100.0, max(0.0, float(pct)))

    def leak(self, pct_s: float) -> None:
        """Drain this much more per second, flying or not (fault injection: a pack failing
        fast); 0 ends it. Clipped to 0..MAX_LEAK_PCT_S."""
        self.leak_pct_s = min(MAX_LEAK_PCT_S, max(0.0, float(pct_s)))

    def wear(self, sag_pct_at_hover: float) -> None:
        """Make the pack sag this much at hover load (fault injection: a cell going bad);
        clipped to 0..MAX_SAG_PCT_AT_HOVER, the most the model allows."""
        self.sag_pct_at_hover = min(MAX_SAG_PCT_AT_HOVER, max(0.0, float(sag_pct_at_hover)))
