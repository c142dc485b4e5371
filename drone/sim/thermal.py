"""How warm the drone gets: a first-order thermal model of its hull, heated by the motors'
load and cooled by the air, read by the barometer on the nav board (navdata tag 21).

The AR.Drone 2.0 reports no motor temperature; the one temperature its navdata carries that
ardrone_autonomy publishes (``temp``) is the barometer's compensated reading in the raw-pressure
option (``navdata_pressure_raw_t.Temperature_meas``, 0.1 °C), on the nav board inside the hull
next to the battery. The simulator reports there the air temperature plus the hull's rise
above it, which follows a first-order lag (one thermal capacity, one conductance to the air):

    d(rise)/dt = (rise_ss − rise) / τ,   rise_ss = RISE_AT_HOVER_C · load²

``load`` is the current relative to hover (``drone.sim.battery.load_factor``: 0 motors off, 1
hover, 1.5 full climb) times the payload's factor; the heat of the motors' windings and the
motor controllers' switches is I²R, so the steady rise grows with the square of the current. A
payload ``m`` on the airframe's mass ``M`` needs thrust × (M + m)/M, and by momentum theory the
power of a hovering rotor grows with thrust^1.5 (Leishman, *Principles of Helicopter
Aerodynamics*, 2nd ed., §2.3): the current, at a fixed battery voltage, by the same factor.
Landed, the propellers' draught stops and the hull cools by natural convection only: a longer
time constant.

The constants are model assumptions, not AR.Drone measurements (Parrot publishes none): a rise
of 25 °C at hover (small brushless motors and their controllers settle some tens of degrees
above the air in sustained hover), minutes to settle in flight (``TAU_FLYING_S``), several times
that on the ground. A normal flight stays below the supervisor's warning on any day up to 30 °C;
a heavy one (a payload, long climbs) or a hot day does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drone.sim.errors import SimConfigError

AIRFRAME_KG = 0.42  # AR.Drone 2.0 with the indoor hull (Parrot's specification: 420 g)
MAX_PAYLOAD_KG = 0.25  # a bound for bad input, above what the airframe is built to lift
RISE_AT_HOVER_C = 25.0  # steady rise of the hull above the air at hover current (assumed)
TAU_FLYING_S = 180.0  # time constant with the propellers' draught (assumed: minutes)
TAU_LANDED_S = 600.0  # natural convection only, on the ground (assumed: several times slower)


def payload_factor(payload_kg: float) -> float:
    """Current at hover with ``payload_kg`` on board, relative to the bare airframe's."""
    return float(((AIRFRAME_KG + payload_kg) / AIRFRAME_KG) ** 1.5)


@dataclass
class Thermal:
    """The hull's rise above the air, °C; ``step`` is called by the simulator every tick."""

    rise_c: float = 0.0
    payload_kg: float = 0.0

    def carry(self, payload_kg: float) -> None:
        """Put ``payload_kg`` on the airframe (0 removes it).

        Raises:
            SimConfigError: negative, not finite, or more than :data:`MAX_PAYLOAD_KG`.
        """
        if not (math.isfinite(payload_kg) and 0.0 <= payload_kg <= MAX_PAYLOAD_KG):
            raise SimConfigError(f"payload must be 0..{MAX_PAYLOAD_KG} kg, got {payload_kg!r}")
        self.payload_kg = payload_kg

    def step(self, dt: float, battery_load: float, motors_on: bool) -> None:
        """Advance ``dt`` seconds at ``battery_load`` (current relative to hover)."""
        load = battery_load * payload_factor(self.payload_kg) if motors_on else 0.0
        target = RISE_AT_HOVER_C * load * load
        tau = TAU_FLYING_S if motors_on else TAU_LANDED_S
        self.rise_c += (target - self.rise_c) * (1.0 - math.exp(-dt / tau))
