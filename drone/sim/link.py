"""``InMemoryLink``: the driver core and the simulator joined by bytes, with no sockets.

Lockstep flights run the real code path — :class:`~drone.ardrone.protocol.DriverProtocol` encodes
AT datagrams, :class:`~drone.sim.drone.SimDrone` parses them, and navdata bytes go back the same
way — on a virtual clock, far faster than real time and deterministic for a seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from drone.ardrone.protocol import DriverEvent, DriverProtocol
from drone.sim.drone import SimDrone
from drone.sim.errors import SimConfigError


@dataclass
class LinkStats:
    at_datagrams: int = 0
    at_bytes: int = 0
    navdata_packets: int = 0
    navdata_bytes: int = 0
    init_datagrams: int = 0


@dataclass
class InMemoryLink:
    """Pumps bytes between ``protocol`` and ``sim``; ``step(now, dt)`` is one lockstep tick.

    ``now`` is the driver's (virtual) clock; the simulator keeps its own (``sim.time``, advanced
    by ``dt`` each tick), so the two may differ by a constant offset. A tick: driver → sim
    datagrams due at ``now``; ``sim.step(dt)``; sim → driver navdata stamped ``now + dt``;
    time-only driver events. Returns the driver's events of the tick.

    ``connect()`` must have been called on the protocol (``InMemoryLink.start`` does it).
    """

    protocol: DriverProtocol
    sim: SimDrone
    stats: LinkStats = field(default_factory=LinkStats)

    def start(self, now: float | None = None) -> None:
        """``protocol.connect`` at ``now`` (default ``sim.time``)."""
        self.protocol.connect(self.sim.time if now is None else now)

    def step(self, now: float, dt: float) -> list[DriverEvent]:
        """Advance one tick of ``dt`` seconds starting at ``now``.

        Raises:
            SimConfigError: ``dt`` negative or not finite.
        """
        p, s, st = self.protocol, self.sim, self.stats
        # The simulator is always given its own clock (sim.time), so a rig whose virtual clock
        # does not start at 0 still gets the drone's 2 s command watchdog right.
        for d in p.navdata_requests_due(now):
            st.init_datagrams += 1
            s.receive_navdata_request(d, s.time)
        for d in p.datagrams_due(now):
            st.at_datagrams += 1
            st.at_bytes += len(d)
            s.receive_at(d, s.time)
        s.step(dt)
        later = now + dt
        events: list[DriverEvent] = []
        packet = s.navdata_due(s.time)
        if packet is not None:
            st.navdata_packets += 1
            st.navdata_bytes += len(packet)
            events.extend(p.receive_navdata(packet, later))
        events.extend(p.poll_events(later))
        return events

    def run(self, duration_s: float, dt: float = 0.01) -> list[DriverEvent]:
        """Step from ``sim.time`` for ``duration_s`` seconds in ticks of ``dt``; all events.

        Raises:
            SimConfigError: ``dt`` not positive.
        """
        if not dt > 0:
            raise SimConfigError(f"dt must be positive, got {dt!r}")
        events: list[DriverEvent] = []
        n = round(duration_s / dt)
        for _ in range(n):
            events.extend(self.step(self.sim.time, dt))
        return events
