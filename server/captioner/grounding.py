"""Marker ids in a scene description come from the ArUco detector, not the captioner.

The captioner sees a marker as a black-and-white square; its guess at the id ("marker 0") is a
language-model guess, wrong most of the time. The detector (cv2.aruco on the same camera,
drone/perception/markers.py) reads the id exactly. ``ground_marker_ids`` rewrites each
"marker N" of a caption with the id of a detected marker on the same side of the image, drops
an id no detection supports ("a marker"), and names detected markers the caption left out.

Sides use the simulator's labelling rule (drone/sim/camera.py ``SIDE_DEG``: more than 15° off
the optical axis is left or right), so captions and detections split the image the same way.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

SIDE_DEG = 15.0  # as drone/sim/camera.py labels the captioner's training scenes
# "marker 7" and the words of its own phrase (up to the next "and", comma or full stop).
_MENTION = re.compile(r"\bmarker (\d+)\b(?P<after>(?:(?! and )[^,.;])*)")


@dataclass(frozen=True)
class SeenMarker:
    """One ArUco detection: its id and bearing from the camera axis (degrees, left positive)."""

    id: int
    bearing_deg: float

    @property
    def side(self) -> str:
        if self.bearing_deg > SIDE_DEG:
            return "left"
        if self.bearing_deg < -SIDE_DEG:
            return "right"
        return "ahead"


def bearing_deg(
    drone_x: float, drone_y: float, drone_yaw_rad: float, marker_x: float, marker_y: float
) -> float:
    """Bearing of a marker from the drone's heading (map frame, REP 103: left is positive)."""
    angle = math.atan2(marker_y - drone_y, marker_x - drone_x) - drone_yaw_rad
    return math.degrees(math.atan2(math.sin(angle), math.cos(angle)))


def seen_markers(snapshot: Any) -> list[SeenMarker]:
    """The detector's markers in a vehicle snapshot (``drone.vehicle.VehicleSnapshot``).

    Each detection carries the drone pose it implies and the marker's map pose, so its bearing
    from the camera axis follows without the image.
    """
    return [
        SeenMarker(int(m.id), bearing_deg(m.x, m.y, m.yaw_rad, m.marker_x, m.marker_y))
        for m in snapshot.markers
    ]


def _side_of(words: str) -> str | None:
    for side, keys in (("left", ("left",)), ("right", ("right",)), ("ahead", ("ahead", "front"))):
        if any(k in words for k in keys):
            return side
    return None


def _join(ids: Sequence[int]) -> str:
    names = [str(i) for i in ids]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def ground_marker_ids(caption: str, seen: Sequence[SeenMarker]) -> str:
    """``caption`` with every marker id taken from ``seen`` (the detector's markers now)."""
    unused = list(seen)

    def pick(m: re.Match[str]) -> str:
        side = _side_of(m.group("after"))
        choice = next((s for s in unused if s.side == side), None)
        if choice is None:
            choice = next((s for s in unused if s.id == int(m.group(1))), None)
        if choice is None and unused:
            choice = unused[0]
        if choice is None:
            return "a marker" + m.group("after")
        unused.remove(choice)
        return f"marker {choice.id}" + m.group("after")

    text = _MENTION.sub(pick, caption)
    if unused:
        ids = sorted(s.id for s in unused)
        noun = "Marker" if len(ids) == 1 else "Markers"
        text = text.rstrip()
        sep = "" if not text or text.endswith(".") else "."
        text = f"{text}{sep} {noun} {_join(ids)} in view.".strip()
    return text
