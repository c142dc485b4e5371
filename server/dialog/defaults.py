"""Slots an operator leaves out, filled by a stated convention before the task manager sees them.

The NLU omits slots the speaker did not state (DESIGN §4). Two everyday sentences leave out a
slot the task needs: "turn around" / "rotate 90" (no direction) and "patrol all markers" (no
list). Rather than answer with a task manager's internal message ("'turn' needs 'direction'"),
the dialog fills them and the reply reads the filled command back, so the operator hears what
will happen ("Turning left 90 degrees").

Conventions: an unstated turn is counter-clockwise ("left"), the positive yaw of REP 103 that
the map frame uses (docs/CONVENTIONS.md); an unstated patrol visits every marker of the world
in id order.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

DEFAULT_TURN_DIRECTION = "left"  # counter-clockwise, REP 103 positive yaw


def fill_defaults(
    commands: Iterable[dict[str, Any]], marker_ids: Iterable[int]
) -> list[dict[str, Any]]:
    """Copies of ``commands`` with the conventions above applied (others unchanged)."""
    markers = sorted(int(m) for m in marker_ids)
    out: list[dict[str, Any]] = []
    for cmd in commands:
        c = dict(cmd)
        if c.get("action") == "turn" and "direction" not in c and "angle" in c:
            c["direction"] = DEFAULT_TURN_DIRECTION
        elif (
            c.get("action") == "patrol"
            and not (c.get("markers") or c.get("waypoints"))  # waypoints are left as said
            and markers
        ):
            c["markers"] = markers
        out.append(c)
    return out
