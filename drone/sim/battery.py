"""AR.Drone 2.0 battery model: state of charge in percent, drained by flight.

The stock 1000 mAh pack gives about 12 minutes of flight (Parrot's specification for the AR.Drone
2.0), so hovering drains 100 % in 720 s; climbing costs more thrust, modelled as up to +50 % drain
at full ``control_vz_max``. Landed with motors off the electronics draw little. The drone sets the
VBAT_LOW state bit below 20 % and refuses to take off while it is set (firmware behaviour reported
in the Developer Guide §7.1.2 state bits and by ARDroneLib's ``ARDRONE_VBAT_LOW``).
"""

from __future__ import annotations

from dataclasses import dataclass

LOW_PCT = 20.0  # VBAT_LOW bit below this
FLIGHT_TIME_S = 720.0  # ~12 min from 100 % at hover
IDLE_DRAIN_PCT_S = 0.005  # motors off (Wi-Fi, cameras, CPU)
CLIMB_EXTRA = 0.5  # extra drain fraction at full climb rate


@dataclass
class Battery:
    """Mutable state of charge; ``step`` is called by the physics at every tick."""

    pct: float = 100.0
    flight_time_s: float = FLIGHT_TIME_S
    low_pct: float = LOW_PCT

    def step(self, dt: float, motors_on: bool, climb_fraction: float = 0.0) -> None:
        """Drain for ``dt`` seconds; ``climb_fraction`` is vz_up / control_vz_max (clipped 0..1)."""
        if motors_on:
            rate = (
                100.0
                / self.flight_time_s
                * (1.0 + CLIMB_EXTRA * min(max(climb_fraction, 0.0), 1.0))
            )
        else:
            rate = IDLE_DRAIN_PCT_S
        self.pct = max(0.0, self.pct - rate * dt)

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
