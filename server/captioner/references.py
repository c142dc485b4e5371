"""Ground-truth captions from a scene graph, and object mentions read back from a caption.

The dataset generator turns what the simulator's camera sees (:class:`SceneItem`) into several
reference sentences with varied wording; evaluation parses any caption back into mentions
(kind, colour, side) to score whether it names what is really there.

Salience: items of the same kind, colour, side and distance form a group ("two red chairs on the
left"); groups are ranked by image area and at most :data:`MAX_GROUPS` are mentioned, the way a
person names the most prominent things in view.
"""

from __future__ import annotations

import random
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

Side = Literal["left", "ahead", "right"]
SIDES: tuple[Side, ...] = ("left", "ahead", "right")
MAX_GROUPS = 3

NUMBERS = {1: "a", 2: "two", 3: "three"}
IRREGULAR_PLURALS = {"person": "people", "shelf": "shelves", "box": "boxes"}

# Location phrases per (side, near); the first of each list is the canonical wording.
LOCATIONS: dict[tuple[str, bool], tuple[str, ...]] = {
    ("left", True): ("close on the left", "near you on the left", "just to the left"),
    ("left", False): ("far off on the left", "in the distance on the left", "far to the left"),
    ("right", True): ("close on the right", "near you on the right", "just to the right"),
    ("right", False): ("far off on the right", "in the distance on the right", "far to the right"),
    ("ahead", True): ("close ahead", "close in front", "just ahead"),
    ("ahead", False): ("far ahead", "in the distance ahead", "further ahead"),
}
SIDE_WORDS: dict[str, Side] = {"left": "left", "right": "right", "ahead": "ahead", "front": "ahead"}
OPENERS_ONE = ("there is", "i can see", "i see", "")
OPENERS_MANY = ("there are", "i can see", "i see", "")
EMPTY = ("nothing in view", "i see nothing", "there is nothing in view", "no objects in view")


@dataclass(frozen=True)
class SceneItem:
    """One visible thing: kind (singular noun, e.g. ``chair``, ``marker``), colour (or None),
    side of the image, near/far, share of the image area, and the marker id for markers."""

    kind: str
    colour: str | None
    side: Side
    near: bool
    area: float
    marker_id: int | None = None


@dataclass(frozen=True)
class Group:
    """Items described together: same kind, colour, side and distance (markers stay single)."""

    kind: str
    colour: str | None
    side: Side
    near: bool
    count: int
    area: float
    marker_id: int | None = None


@dataclass(frozen=True)
class Mention:
    """What a caption says about one thing: kind, colour (or None) and side (or None)."""

    kind: str
    colour: str | None = None
    side: Side | None = None
    marker_id: int | None = None


def plural(kind: str) -> str:
    """English plural of a kind noun (``person`` -> ``people``, ``shelf`` -> ``shelves``)."""
    if kind in IRREGULAR_PLURALS:
        return IRREGULAR_PLURALS[kind]
    return kind + ("es" if kind.endswith(("s", "sh", "ch", "x")) else "s")


def salient_groups(items: Iterable[SceneItem], limit: int = MAX_GROUPS) -> list[Group]:
    """Group items and return the ``limit`` largest groups by total area (ties: by name)."""
    buckets: dict[tuple[object, ...], list[SceneItem]] = {}
    for it in items:
        key = (it.kind, it.colour, it.side, it.near, it.marker_id if it.kind == "marker" else None)
        buckets.setdefault(key, []).append(it)
    groups = [
        Group(
            kind=k[0],  # type: ignore[arg-type]
            colour=k[1],  # type: ignore[arg-type]
            side=k[2],  # type: ignore[arg-type]
            near=bool(k[3]),
            count=len(v),
            area=sum(i.area for i in v),
            marker_id=k[4],  # type: ignore[arg-type]
        )
        for k, v in buckets.items()
    ]
    groups.sort(key=lambda g: (-g.area, g.kind, g.colour or "", g.side, g.marker_id or -1))
    return groups[:limit]


def phrase(group: Group, location: str) -> str:
    """Noun phrase plus location: ``two red chairs close on the left``, ``marker 7 far ahead``."""
    if group.kind == "marker" and group.marker_id is not None:
        return f"marker {group.marker_id} {location}"
    count = min(group.count, 3)
    det = NUMBERS[count] if group.count <= 3 else "several"
    noun = group.kind if group.count == 1 else plural(group.kind)
    words = [det]
    if group.colour:
        words.append(group.colour)
    words.append(noun)
    if det == "a" and words[1][0] in "aeiou":
        words[0] = "an"
    return " ".join([*words, location])


def join(parts: Sequence[str]) -> str:
    """``a``, ``a and b``, ``a , b and c`` (the comma is a token of its own)."""
    if len(parts) <= 1:
        return "".join(parts)
    return " , ".join(parts[:-1]) + " and " + parts[-1]


def describe(groups: Sequence[Group], rng: random.Random | None = None) -> str:
    """One caption for ``groups``; ``rng=None`` gives the canonical wording."""

    def pick(options: Sequence[str]) -> str:
        return options[0] if rng is None else rng.choice(list(options))

    if not groups:
        return pick(EMPTY)
    parts = [phrase(g, pick(LOCATIONS[(g.side, g.near)])) for g in groups]
    first = groups[0]
    many = first.count > 1 and first.kind != "marker"
    opener = pick(OPENERS_MANY if many else OPENERS_ONE)
    body = join(parts)
    return f"{opener} {body}".strip()


def references(items: Iterable[SceneItem], n: int, seed: int) -> list[str]:
    """``n`` distinct captions for a scene when possible: the canonical one first, then varied."""
    groups = salient_groups(items)
    rng = random.Random(seed)
    out = [describe(groups)]
    tries = 0
    while len(out) < n and tries < 20 * n:
        tries += 1
        cand = describe(groups, rng)
        if cand not in out:
            out.append(cand)
    while len(out) < n:  # few variants exist (e.g. empty scenes): repeat, keep n references
        out.append(out[len(out) % max(1, len(out))])
    return out


# -- reading mentions back ---------------------------------------------------------------------


def mentions(caption: str, kinds: Iterable[str], colours: Iterable[str]) -> list[Mention]:
    """Things a caption names: each kind noun (singular or plural) with the colour word right
    before it and the side named after it in the same phrase (phrases split at ``and``)."""
    nouns: dict[str, str] = {}
    for k in kinds:
        nouns[k] = k
        nouns[plural(k)] = k
    colour_words = sorted(colours, key=lambda c: -len(c.split()))  # "light blue" before "blue"
    words = caption.lower().replace(",", " , ").replace(".", " ").split()
    phrases: list[list[str]] = [[]]
    for w in words:
        if w in ("and", ","):
            phrases.append([])
        else:
            phrases[-1].append(w)
    found: list[Mention] = []
    for ph in phrases:
        for i, w in enumerate(ph):
            if w not in nouns:
                continue
            colour = None
            for c in colour_words:
                cw = c.split()
                if i >= len(cw) and ph[i - len(cw) : i] == cw:
                    colour = c
                    break
            rest = ph[i + 1 :]
            side = next((SIDE_WORDS[r] for r in rest if r in SIDE_WORDS), None)
            marker_id = int(rest[0]) if w == "marker" and rest and rest[0].isdigit() else None
            found.append(Mention(nouns[w], colour, side, marker_id))
    return found
