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


# -- the whole sentence grounded in the image ---------------------------------------------------

# Thresholds chosen on the tuning set (server.captioner.evalset.TUNING_SEED_BASE: seeds
# 3 100 000+, bench/describe.py --start 3100000), never on the reported one (3 000 000+).
CAPTION_MIN_P = 0.1
"""A kind the captioner names is kept when a region on its side is at least this likely to be
one (the captioner has seen the whole image; the region classifier confirms it is there)."""
CAPTION_RIVAL_RATIO = 0.5
"""...unless the classifier finds another kind for that region this many times likelier (then
the region is left to the classifier: a white shelf the captioner calls a door)."""
CAPTION_ELSEWHERE_P = 0.5
"""A kind the captioner names on a side where no region supports it is taken from a region on
another side whose likeliest kind it is, at least this likely (the captioner's kinds are
more often right than its sides)."""
DETECT_MIN_P = 0.5
"""A region the captioner left out is named with its likeliest kind when the classifier is
this sure..."""
DETECT_MIN_P_KIND = {"shelf": 0.8}
"""...or, for kinds it takes other things for more often (a door or a wall face seen as a
shelf), this sure..."""
DETECT_MARGIN = 2.0
"""...and that kind is at least this many times likelier than any other (a region that is as
likely a box as a sofa is not named either)."""
DETECT_MIN_AREA = 0.004
MAX_THINGS = 5
"""At most this many objects are named (largest first), plus every detected marker."""


@dataclass(frozen=True)
class Thing:
    """An object a grounded description names: kind, colour of its region, side, image share."""

    kind: str
    colour: str
    side: str
    area: float


def _location(side: str) -> str:
    return "ahead" if side == "ahead" else f"on the {side}"


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _touch(a: tuple[int, int, int, int], b: tuple[int, int, int, int], pad: int = 2) -> bool:
    return a[0] - pad < b[2] and b[0] - pad < a[2] and a[1] - pad < b[3] and b[1] - pad < a[3]


def ground_objects(caption: str, regions: Sequence[Any]) -> list[Thing]:
    """The objects to name: the captioner's kinds that a region of the image supports (on the
    captioner's side, or elsewhere when very likely), with the region's colour and side, then
    regions the classifier is sure of (one kind per object: a region touching one already named
    in its colour is taken for another face of it).
    ``regions`` are ``server.captioner.scene.Region`` (largest first)."""
    from server.captioner.references import mentions
    from server.captioner.scene import KINDS, REGION_COLOURS

    free = [r for r in regions if r.probs]
    chosen: list[tuple[Any, str]] = []

    def fits(r: Any, kind: str) -> bool:
        p = r.p(kind)
        return bool(p >= CAPTION_MIN_P and p >= CAPTION_RIVAL_RATIO * max(r.probs[1:]))

    for m in mentions(caption, KINDS[1:], REGION_COLOURS):
        on_side = [r for r in free if (m.side is None or r.side == m.side)]
        on_side = [r for r in on_side if fits(r, m.kind)]
        ranked = sorted(on_side, key=lambda r: (r.p(m.kind) + 0.1 * (r.colour == m.colour), r.area))
        if not ranked:
            elsewhere = [r for r in free if r.kind == m.kind and r.p(m.kind) >= CAPTION_ELSEWHERE_P]
            ranked = sorted(elsewhere, key=lambda r: (r.p(m.kind), r.area))
        best = ranked[-1] if ranked else None
        if best is not None:
            free.remove(best)
            chosen.append((best, m.kind))
    for r in sorted(free, key=lambda r: -max(r.probs[1:])):
        sure = DETECT_MIN_P_KIND.get(r.kind, DETECT_MIN_P)
        runner_up = sorted(r.probs[1:])[-2]
        p = r.p(r.kind)
        if r.kind == "none" or p < sure or p < DETECT_MARGIN * runner_up:
            continue
        if r.area < DETECT_MIN_AREA:  # too few pixels to tell
            continue
        if any(c.colour == r.colour and _touch(c.box, r.box) for c, _ in chosen):
            continue
        chosen.append((r, r.kind))
    merged: dict[tuple[str, str, str], Thing] = {}
    for r, kind in chosen:
        key = (kind, r.colour, r.side)
        old = merged.get(key)
        merged[key] = Thing(kind, r.colour, r.side, r.area + (old.area if old else 0.0))
    return sorted(merged.values(), key=lambda t: -t.area)[:MAX_THINGS]


def sentence(things: Sequence[Thing], markers: Sequence[SeenMarker]) -> str:
    """``I see a brown door ahead, an orange person on the right and marker 4 on the right.``"""
    parts = [f"{_article(t.colour)} {t.colour} {t.kind} {_location(t.side)}" for t in things] + [
        f"marker {m.id} {_location(m.side)}" for m in markers
    ]
    if not parts:
        return "I see nothing I can name."
    body = parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]
    return f"I see {body}."
