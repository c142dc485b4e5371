"""``MavlinkMemoryLink``: the console's protocol and the simulated autopilot joined in memory.

Lockstep (DESIGN §3): each ``step(now, dt)`` carries the protocol's bytes to the autopilot,
advances the autopilot by ``dt`` and carries its bytes back, so the same code that flies over
TCP flies on a virtual clock with no sockets and no sleeping. ``autopilot.inject_fault
("link_loss", …)`` models a lost link; ``tamper`` rewrites bytes in flight (bad-input tests).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from drone.mavlink.gcs.protocol import GcsProtocol
from drone.mavlink.sim.autopilot import SimAutopilot

LINK_ID = "memory"
MAX_SUBSTEP_S = 0.02


class MavlinkMemoryLink:
    """See the module docstring."""

    def __init__(
        self,
        protocol: GcsProtocol,
        autopilot: SimAutopilot,
        *,
        tamper: Callable[[bytes], bytes] | None = None,
    ) -> None:
        self.protocol = protocol
        self.autopilot = autopilot
        self.tamper = tamper
        self.bytes_up = 0
        self.bytes_down = 0
        autopilot.connect(LINK_ID)

    def inject_fault(self, kind: str, **params: float) -> None:
        self.autopilot.inject_fault(kind, **params)

    def step(self, now: float, dt: float) -> list[Any]:
        """One tick; returns the protocol's events."""
        p, ap = self.protocol, self.autopilot
        p.tick(now)
        up = p.data_to_send()
        if up:
            self.bytes_up += len(up)
            ap.receive(LINK_ID, up)  # dropped while an injected link loss lasts
        # the autopilot's physics and controller in sub-steps of at most 20 ms (stable)
        n = max(1, math.ceil(dt / MAX_SUBSTEP_S - 1e-9))
        for _ in range(n):
            ap.step(dt / n)
        down = ap.drain(LINK_ID)
        if down:
            if self.tamper is not None:
                down = self.tamper(down)
            self.bytes_down += len(down)
            p.receive(down, now + dt)
        return p.events()
