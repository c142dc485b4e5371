"""Held-out simulator frames with ground truth, for scoring scene descriptions.

Each frame is its own seed: a world (the shipped indoor room or outdoor field, or either with
its objects replaced by a random set as in ``tools/make_caption_dataset.py``), a random camera
pose (often turned towards a random object or marker), random lighting and sensor noise, and
optionally a JPEG round trip (the server describes decoded video, not the renderer's pixels).
The truth is ``drone.sim.camera.Renderer.visible`` (occlusion-aware id buffer) at that pose.

This module is for evaluation only: nothing here is read when the server describes a frame.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from drone.sim.camera import Renderer, Visible
from drone.sim.world import COLOURS, SceneObject, World, load_world

Variant = Literal["world", "random"]
SEED_BASE = 3_000_000
"""First seed of the held-out description set: far above every seed range
``tools/make_caption_dataset.py`` trains, validates or tests the captioner on."""
TUNING_SEED_BASE = 3_100_000
"""First seed of the tuning set: frames made exactly as the held-out ones, on which the
grounding's thresholds and the region classifier's training are chosen (``bench/describe.py
--start 3100000``), so that the held-out figures are not tuned on."""
MENTION_MIN_AREA = 0.012
MARKER_MIN_AREA = 0.005
"""As in ``tools/make_caption_dataset.py``: smaller things need not be named (recall), but
naming them is not wrong (precision)."""

# Object sizes and palettes of the randomised scenes (tools/make_caption_dataset.py).
_SIZES: dict[str, tuple[float, float, float]] = {
    "chair": (0.45, 0.45, 0.9),
    "table": (1.2, 0.8, 0.75),
    "door": (0.9, 0.05, 2.0),
    "window": (1.0, 0.05, 1.1),
    "person": (0.5, 0.3, 1.72),
    "plant": (0.45, 0.45, 1.1),
    "box": (0.5, 0.5, 0.5),
    "sofa": (1.8, 0.8, 0.85),
    "shelf": (0.8, 0.35, 1.8),
    "lamp": (0.35, 0.35, 1.5),
    "tree": (3.0, 3.0, 6.0),
    "car": (1.8, 4.3, 1.5),
    "post": (0.08, 0.08, 1.25),
}
_INDOOR_KINDS = ("chair", "table", "person", "plant", "box", "sofa", "shelf", "lamp")
_OUTDOOR_KINDS = ("tree", "car", "post", "person", "box")
_PALETTE = (
    "red",
    "green",
    "blue",
    "yellow",
    "orange",
    "purple",
    "pink",
    "brown",
    "white",
    "black",
    "grey",
)


@dataclass(frozen=True)
class TruthLabel:
    """One visible thing: kind, colour (None for markers), side, share of the image, id."""

    kind: str
    colour: str | None
    side: str
    area: float
    marker_id: int | None = None

    @property
    def mentionable(self) -> bool:
        """Large enough that a description should name it (see ``MENTION_MIN_AREA``)."""
        return self.area >= (MARKER_MIN_AREA if self.kind == "marker" else MENTION_MIN_AREA)


@dataclass(frozen=True)
class Sample:
    """A held-out frame (640×360 BGR) and what is really in it."""

    seed: int
    world: str  # "indoor" or "outdoor"
    variant: Variant
    pose: tuple[float, float, float, float, float, float]
    frame: npt.NDArray[np.uint8]
    truth: tuple[TruthLabel, ...]


def _truth(visible: list[Visible]) -> tuple[TruthLabel, ...]:
    return tuple(
        TruthLabel(
            kind=v.kind,
            colour=None if v.kind == "marker" else v.colour,
            side=v.side,
            area=v.area_frac,
            marker_id=v.marker_id,
        )
        for v in visible
    )


def _random_objects(world: World, rng: random.Random) -> tuple[SceneObject, ...]:
    def make(
        i: int, kind: str, colour: str, x: float, y: float, z: float, yaw: float
    ) -> SceneObject:
        w, d, h = _SIZES[kind]
        s = rng.uniform(0.8, 1.25)
        size = (w * s, d, h * s) if kind in ("door", "window") else (w * s, d * s, h * s)
        return SceneObject(f"{kind}{i}", kind, colour, COLOURS[colour], (x, y, z), yaw, size)

    out: list[SceneObject] = []
    b = world.bounds
    if not world.indoor:
        for i in range(rng.randint(1, 5)):
            kind = rng.choice(_OUTDOOR_KINDS)
            r, a = rng.uniform(3.0, 25.0), rng.uniform(-math.pi, math.pi)
            colour = "green" if kind == "tree" else rng.choice(_PALETTE)
            out.append(
                make(i, kind, colour, r * math.cos(a), r * math.sin(a), 0.0, rng.uniform(-3, 3))
            )
        return tuple(out)
    walls = [
        ("x", b.y_min + 0.03, math.pi / 2),
        ("x", b.y_max - 0.03, -math.pi / 2),
        ("y", b.x_min + 0.03, 0.0),
        ("y", b.x_max - 0.03, math.pi),
    ]
    for i in range(rng.choice((0, 1, 1, 2))):
        kind = rng.choice(("door", "window"))
        axis, fixed, yaw = rng.choice(walls)
        lo, hi = (b.x_min, b.x_max) if axis == "x" else (b.y_min, b.y_max)
        t = rng.uniform(lo + 0.8, hi - 0.8)
        x, y = (t, fixed) if axis == "x" else (fixed, t)
        z = 0.0 if kind == "door" else rng.uniform(0.8, 1.1)
        colour = "light blue" if kind == "window" else rng.choice(_PALETTE)
        out.append(make(i, kind, colour, x, y, z, yaw))
    placed: list[tuple[float, float]] = []
    for i in range(rng.choice((1, 2, 3, 3, 4, 5, 6))):
        kind = rng.choice(_INDOOR_KINDS)
        x = y = 0.0
        for _ in range(20):
            x = rng.uniform(b.x_min + 0.5, b.x_max - 0.5)
            y = rng.uniform(b.y_min + 0.5, b.y_max - 0.5)
            if all(math.hypot(x - px, y - py) > 0.9 for px, py in placed):
                break
        placed.append((x, y))
        yaw = rng.uniform(-math.pi, math.pi)
        out.append(make(10 + i, kind, rng.choice(_PALETTE), x, y, 0.0, yaw))
    return tuple(out)


def _pose(world: World, rng: random.Random) -> tuple[float, float, float, float, float, float]:
    """A pose clear of objects, turned towards a random object or marker 60 % of the time."""
    b = world.bounds
    x = y = z = 0.0
    for _ in range(50):
        if world.indoor:
            x = rng.uniform(b.x_min + 0.4, b.x_max - 0.4)
            y = rng.uniform(b.y_min + 0.4, b.y_max - 0.4)
            z = rng.uniform(0.4, 2.2)
        else:
            x, y, z = rng.uniform(-15, 15), rng.uniform(-15, 15), rng.uniform(0.8, 5.0)
        if all(
            math.hypot(x - o.position[0], y - o.position[1]) > max(o.size[0], o.size[1]) / 2 + 0.4
            for o in world.objects
        ):
            break
    targets = [o.position[:2] for o in world.objects] + [m.position[:2] for m in world.markers]
    if targets and rng.random() < 0.6:
        tx, ty = rng.choice(targets)
        yaw = math.atan2(ty - y, tx - x) + math.radians(rng.uniform(-35, 35))
    else:
        yaw = rng.uniform(-math.pi, math.pi)
    yaw = (yaw + math.pi) % (2 * math.pi) - math.pi
    return (x, y, z, math.radians(rng.uniform(-4, 4)), math.radians(rng.uniform(-4, 6)), yaw)


def scene(
    seed: int, worlds: dict[str, World] | None = None
) -> tuple[str, Variant, World, tuple[float, float, float, float, float, float], Renderer]:
    """The scene of ``seed``: world name, variant, world, camera pose and its renderer.

    Seeds alternate indoors/outdoors, and in pairs the world as shipped / a randomised set of
    objects; lighting ×0.7–1.3, sensor noise σ 0–4, vignetting 0–25.
    """
    worlds = worlds or {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")}
    rng = random.Random(seed)
    name = "indoor" if seed % 2 == 0 else "outdoor"
    base = worlds[name]
    variant: Variant = "world" if (seed // 2) % 2 == 0 else "random"
    world = base if variant == "world" else base.with_objects(_random_objects(base, rng))
    pose = _pose(world, rng)
    renderer = Renderer(
        world,
        seed=seed,
        brightness=rng.uniform(0.7, 1.3),
        noise_sigma=rng.uniform(0.0, 4.0),
        vignette=rng.uniform(0.0, 25.0),
    )
    return name, variant, world, pose, renderer


def sample(seed: int, worlds: dict[str, World] | None = None) -> Sample:
    """The held-out frame of ``seed`` (deterministic; see :func:`scene`). Half the frames
    pass through JPEG (quality 60–90), as the video path blurs them."""
    name, variant, _, pose, renderer = scene(seed, worlds)
    frame = renderer.render(pose, frame=seed)
    rng = random.Random(seed + 1)
    if rng.random() < 0.5:
        ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, rng.randint(60, 90)])
        assert ok
        frame = np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR), np.uint8)
    # every thing with a pixel in view counts as there (naming it is not wrong)
    return Sample(seed, name, variant, pose, frame, _truth(renderer.visible(pose, 0.0)))


def samples(n: int, start: int = SEED_BASE) -> Iterator[Sample]:
    """``n`` held-out samples from seed ``start`` on (both worlds, alternating)."""
    worlds = {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")}
    for i in range(n):
        yield sample(start + i, worlds)
