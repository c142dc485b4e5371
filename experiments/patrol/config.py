"""The patrol experiment's knobs."""

from __future__ import annotations

from dataclasses import dataclass

MAX_DRONES = 16


@dataclass(frozen=True)
class PatrolConfig:
    """Experiment knobs (defaults: the paper's mission with AR.Drone 2.0 batteries)."""

    drones: int = 2
    duration_s: float = 3600.0
    threshold: float = 0.30
    seed: int = 0
    # Tick: 0.1 s is the coarsest at which the paper PID still tracks (same coverage and gaps
    # as 0.05 s and 0.01 s, bench/fleet.py); the physics integrates its lags exactly.
    dt: float = 0.1
    flight_time_s: float | None = None  # battery: 100 % → 0 % hovering (None: 720 s)
    swap_s: float = 120.0
    charge_pct_s: float | None = None
    fail_at_s: float | None = None
    fail_kind: str = "emergency"  # emergency (motors cut) | link (drone link lost 60 s)
    ctm_period_s: float = 0.5
    status_period_s: float = 1.0
    lost_after_s: float = 3.0
    ctm_timeout_s: float = 15.0
    corridor_m: float = 2.5
    continuity: bool = True  # relief joins where the patrolling drone goes next (continuity.py)
    handoff: str = "predictive"  # or "reactive" (the paper's rule), server.fleet.messages.Handoff
    protocol: str = "ardrone"  # "mavlink": simulated PX4 quadrotors
