"""Issue 13 §2: flight limits belong to the world (``limits:`` in its file, drone/limits.py)."""

from __future__ import annotations

from typing import Any

import pytest

from drone.limits import limits_of
from drone.sim.world import WorldError, load_world, parse_world


def _room(**extra: Any) -> dict[str, Any]:
    return {
        "name": "room",
        "bounds": {"x_min": 0, "x_max": 5, "y_min": 0, "y_max": 4, "z_min": 0, "z_max": 3},
        **extra,
    }


def test_defaults_and_the_world_file_limits() -> None:
    indoor, outdoor = limits_of(load_world("indoor")), limits_of(load_world("outdoor"))
    assert (indoor.ceiling_m, indoor.floor_m, indoor.wall_margin_m) == (2.7, 0.3, 0.35)
    assert outdoor.ceiling_m == 20.0 and not outdoor.indoor
    low = limits_of(parse_world(_room(limits={"ceiling_m": 2.0, "wall_margin_m": 0.5})))
    assert (low.ceiling_m, low.wall_margin_m) == (2.0, 0.5)
    assert load_world("outdoor").to_dict()["limits"]["ceiling_m"] == 20.0


@pytest.mark.parametrize(
    ("limits", "message"),
    [
        ({"ceiling_m": 5.0}, "ceiling_m <= 3"),
        ({"floor_m": 2.0, "ceiling_m": 1.0}, "floor_m < ceiling_m"),
        ({"roof_m": 2.0}, "limits.roof_m: unknown limit"),
        ({"ceiling_m": "high"}, "limits.ceiling_m: expected a number"),
        ([1, 2], "limits: expected a mapping"),
    ],
)
def test_bad_limits_name_the_field(limits: Any, message: str) -> None:
    with pytest.raises(WorldError, match=message):
        parse_world(_room(limits=limits), source="room.yaml")


def test_violations_say_why() -> None:
    lim = limits_of(load_world("indoor"))
    assert lim.violation(4.0, 3.0, 1.5) is None
    assert lim.violation(7.9, 3.0, 1.5) == (
        "(7.9, 3.0) is outside the room (8 × 6 m, keeping 0.35 m from its edges)"
    )
    assert lim.violation(4.0, 3.0, 2.9) == "a height of 2.9 m is above this room's ceiling of 2.7 m"
    assert lim.violation(4.0, 3.0, 0.1) == (
        "a height of 0.1 m is below the lowest safe height of 0.3 m"
    )


def test_a_vertical_move_is_judged_on_height_alone_and_towards_safety_always_allowed() -> None:
    """A climb or descent never crosses the fence, so a drone whose estimate is outside it may
    still descend; and one above the ceiling may always descend (the altitude monitor's
    corrective "move down" was refused by the fence and the drone held above the ceiling)."""
    from types import SimpleNamespace

    from drone.commands import Move
    from server.tasks.base import PlanState
    from server.tasks.errors import RefusedError
    from server.tasks.motion import MoveTask

    lim = limits_of(load_world("indoor"))  # ceiling 2.7 m, floor limit 0.3 m
    assert lim.vertical_violation(3.5, 3.0) is None  # descending from above the ceiling
    assert lim.vertical_violation(2.0, 1.0) is None
    assert "ceiling" in (lim.vertical_violation(2.0, 3.0) or "")  # climbing through it
    assert "ceiling" in (lim.vertical_violation(3.0, 3.5) or "")  # climbing above it
    assert lim.vertical_violation(0.1, 0.2) is None  # climbing from below the floor limit
    assert "lowest safe height" in (lim.vertical_violation(1.0, 0.2) or "")

    ctx = SimpleNamespace(limits=lim)
    outside = PlanState(flying=True, x=3.6, y=13.5, z=3.2, yaw_rad=0.0)  # estimate off the room
    down = MoveTask(Move(action="move", direction="down", distance=0.8))
    assert down.plan(outside, ctx).z == 3.2 - 0.8  # type: ignore[arg-type]
    up = MoveTask(Move(action="move", direction="up", distance=0.5))
    with pytest.raises(RefusedError, match="ceiling"):
        up.plan(outside, ctx)  # type: ignore[arg-type]
    forward = MoveTask(Move(action="move", direction="forward", distance=0.5))
    with pytest.raises(RefusedError, match="outside the"):
        forward.plan(outside, ctx)  # type: ignore[arg-type]
