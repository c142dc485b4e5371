"""What a vehicle process shares with its consoles: the graph topics it publishes on the bus
(``uavc/<fleet>/<drone>/graph/<topic>``, docs/bus.md), each with its message type."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TopicSpec:
    """One graph topic: its canonical name (with the fleet prefix), type, and whether it is
    latched (published again for a console that joins later)."""

    name: str
    type: str
    latch: bool = False
