"""Render a captioning dataset from the simulator's worlds, with ground truth from its scene graph.

Each sample is its own seed: a world (indoor room, or the outdoor field in a share of samples)
whose objects are replaced by a random set (kinds, colours, sizes, placements), a random camera
pose (often turned towards an object), random lighting; the image comes from
``drone.sim.camera.Renderer`` and the captions from ``Renderer.visible`` (occlusion-aware) via
``server.captioner.references``. Splits use disjoint seed ranges, so held-out scenes are new
placements, poses and lighting.

    .venv/bin/python tools/make_caption_dataset.py --out data/captions --train 4000

Writes ``{train,val,test}.npz`` (``images``: uint8 BGR ``[N, 96, 160, 3]``, resized exactly as the
captioner resizes frames) and ``{split}.jsonl`` (one record per image: seed, world, pose,
references, mentionable items, all visible items).
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drone.sim.camera import Renderer, Visible
from drone.sim.world import COLOURS, SceneObject, World, load_world
from server.captioner.model import resize
from server.captioner.references import SceneItem, references

INPUT_HW = (96, 160)
N_REFS = 5
MENTION_MIN_AREA = 0.012
MARKER_MIN_AREA = 0.005
"""Objects covering less of the image than this (markers: ``MARKER_MIN_AREA``) are left out of
the references: a person names what is prominent, and at the model's 96×160 input a smaller
object is a few pixels wide. They still count as really visible when scoring precision."""
SEED_BASE = {
    "train": 0,
    "train2": 500_000,
    "train3": 700_000,
    "val": 1_000_000,
    "test": 2_000_000,
}
"""First seed of each split; ``train2`` and ``train3`` are optional extra training data."""

# Typical (width, depth, height) in metres; scaled by 0.8–1.25 per sample.
SIZES: dict[str, tuple[float, float, float]] = {
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
INDOOR_FLOOR_KINDS = ("chair", "table", "person", "plant", "box", "sofa", "shelf", "lamp")
OUTDOOR_KINDS = ("tree", "car", "post", "person", "box")
PALETTE = (
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
WINDOW_COLOURS = ("light blue",)
KINDS = ("marker", *sorted(SIZES))
COLOUR_NAMES = tuple(sorted(COLOURS))


def to_items(visible: list[Visible], min_area: float = 0.0) -> list[SceneItem]:
    """The renderer's scene graph as caption items (markers have no colour, keep their id)."""
    return [
        SceneItem(
            kind=v.kind,
            colour=None if v.kind == "marker" else v.colour,
            side=v.side,
            near=v.near,
            area=round(v.area_frac, 6),
            marker_id=v.marker_id,
        )
        for v in visible
        if v.area_frac >= min_area
    ]


def _obj(
    rng: random.Random, i: int, kind: str, colour: str, x: float, y: float, z: float, yaw: float
) -> SceneObject:
    w, d, h = SIZES[kind]
    s = rng.uniform(0.8, 1.25)
    size = (w * s, d, h * s) if kind in ("door", "window") else (w * s, d * s, h * s)
    return SceneObject(
        id=f"{kind}{i}",
        kind=kind,
        colour=colour,
        bgr=COLOURS[colour],
        position=(x, y, z),
        yaw_rad=yaw,
        size=size,
    )


def indoor_objects(world: World, rng: random.Random) -> list[SceneObject]:
    """0–6 random floor objects, plus doors/windows on the walls."""
    b = world.bounds
    objs: list[SceneObject] = []
    n_wall = rng.choice((0, 0, 1, 1, 2))
    walls = [  # (axis along, fixed coordinate, inward yaw)
        ("x", b.y_min + 0.03, math.pi / 2),
        ("x", b.y_max - 0.03, -math.pi / 2),
        ("y", b.x_min + 0.03, 0.0),
        ("y", b.x_max - 0.03, math.pi),
    ]
    for i in range(n_wall):
        kind = rng.choice(("door", "window"))
        axis, fixed, yaw = rng.choice(walls)
        lo, hi = (b.x_min, b.x_max) if axis == "x" else (b.y_min, b.y_max)
        t = rng.uniform(lo + 0.8, hi - 0.8)
        x, y = (t, fixed) if axis == "x" else (fixed, t)
        z = 0.0 if kind == "door" else rng.uniform(0.8, 1.1)
        colour = rng.choice(WINDOW_COLOURS if kind == "window" else PALETTE)
        objs.append(_obj(rng, i, kind, colour, x, y, z, yaw))
    n_floor = rng.choice((0, 1, 1, 2, 2, 3, 3, 4, 5, 6))
    placed: list[tuple[float, float]] = []
    for i in range(n_floor):
        kind = rng.choice(INDOOR_FLOOR_KINDS)
        for _ in range(20):
            x = rng.uniform(b.x_min + 0.5, b.x_max - 0.5)
            y = rng.uniform(b.y_min + 0.5, b.y_max - 0.5)
            if all(math.hypot(x - px, y - py) > 0.9 for px, py in placed):
                break
        placed.append((x, y))
        objs.append(
            _obj(rng, 10 + i, kind, rng.choice(PALETTE), x, y, 0.0, rng.uniform(-math.pi, math.pi))
        )
    return objs


def outdoor_objects(rng: random.Random) -> list[SceneObject]:
    """1–5 objects within 3–25 m of the origin (the drone flies near it)."""
    objs = []
    for i in range(rng.randint(1, 5)):
        kind = rng.choice(OUTDOOR_KINDS)
        r = rng.uniform(3.0, 25.0)
        a = rng.uniform(-math.pi, math.pi)
        colour = "green" if kind == "tree" else rng.choice(PALETTE)
        objs.append(
            _obj(rng, i, kind, colour, r * math.cos(a), r * math.sin(a), 0.0, rng.uniform(-3, 3))
        )
    return objs


def random_pose(world: World, objects: list[SceneObject], rng: random.Random) -> tuple[float, ...]:
    """A camera pose clear of objects; often turned towards one (bearing noise ±40°)."""
    b = world.bounds
    for _ in range(50):
        if world.indoor:
            x = rng.uniform(b.x_min + 0.4, b.x_max - 0.4)
            y = rng.uniform(b.y_min + 0.4, b.y_max - 0.4)
            z = rng.uniform(0.4, 2.2)
        else:
            x, y, z = rng.uniform(-8, 8), rng.uniform(-8, 8), rng.uniform(0.8, 4.0)
        clear = all(
            math.hypot(x - o.position[0], y - o.position[1]) > max(o.size[0], o.size[1]) / 2 + 0.35
            for o in objects
        )
        if clear:
            break
    if objects and rng.random() < 0.7:
        o = rng.choice(objects)
        yaw = math.atan2(o.position[1] - y, o.position[0] - x) + math.radians(rng.uniform(-40, 40))
    else:
        yaw = rng.uniform(-math.pi, math.pi)
    roll = math.radians(rng.uniform(-4, 4))
    pitch = math.radians(rng.uniform(-4, 6))
    return (x, y, z, roll, pitch, (yaw + math.pi) % (2 * math.pi) - math.pi)


def scene(
    seed: int, worlds: dict[str, World]
) -> tuple[str, World, tuple[float, ...], dict[str, float]]:
    """The random scene of a seed: world name, world with objects, pose, renderer settings."""
    rng = random.Random(seed)
    name = "outdoor" if rng.random() < 0.15 else "indoor"
    base = worlds[name]
    objects = indoor_objects(base, rng) if base.indoor else outdoor_objects(rng)
    world = base.with_objects(tuple(objects))
    pose = random_pose(world, objects, rng)
    look = {
        "brightness": rng.uniform(0.65, 1.35),
        "noise_sigma": rng.uniform(0.0, 4.0),
        "vignette": rng.uniform(0.0, 25.0),
    }
    return name, world, pose, look


def make_sample(
    seed: int, worlds: dict[str, World]
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Render one sample: (full 640×360 BGR frame, resized frame, record)."""
    name, world, pose, look = scene(seed, worlds)
    renderer = Renderer(world, seed=seed, **look)
    frame = renderer.render(pose, frame=seed)
    seen = to_items(renderer.visible(pose))
    record = label({"seed": seed, "world": name, "pose": [round(v, 4) for v in pose]}, seen)
    return frame, resize(frame, INPUT_HW), record


CELL_GRID = (12, 20)


def cell_labels(
    world: World, pose: tuple[float, ...], grid: tuple[int, int] = CELL_GRID
) -> np.ndarray:
    """Dense training labels ``[2, gh, gw]`` uint8 per grid cell: [0] 1 + the index in ``KINDS``
    of the thing covering most of the cell if it covers at least a quarter of it, else 0 (walls,
    floor, sky); [1] that thing's colour index in ``COLOUR_NAMES``, 255 for none (markers,
    background)."""
    renderer = Renderer(world, noise_sigma=0.0, vignette=0.0)
    ids = renderer.render_ids(pose, 0.5).astype(np.int64)  # 0 background, objects, markers
    n_obj = len(world.objects)
    gh, gw = grid
    h, w = ids.shape
    ch, cw = h // gh, w // gw
    flat = ids[: gh * ch, : gw * cw].reshape(gh, ch, gw, cw).transpose(0, 2, 1, 3)
    flat = flat.reshape(gh, gw, -1)
    n_things = 1 + n_obj + len(world.markers)
    counts = np.zeros((gh, gw, n_things), np.int64)
    for k in range(1, n_things):
        counts[..., k] = (flat == k).sum(axis=2)
    best = counts.argmax(axis=2)
    covered = counts.max(axis=2) >= 0.25 * ch * cw
    kind_lut = np.array(
        [0]
        + [1 + KINDS.index(o.kind) for o in world.objects]
        + [1 + KINDS.index("marker")] * len(world.markers),
        np.int64,
    )
    colour_lut = np.array(
        [255] + [COLOUR_NAMES.index(o.colour) for o in world.objects] + [255] * len(world.markers),
        np.int64,
    )
    kinds = np.where(covered, kind_lut[best], 0)
    colours = np.where(covered, colour_lut[best], 255)
    return np.stack([kinds, colours]).astype(np.uint8)


def write_cells(out: Path, worlds: dict[str, World]) -> None:
    """``{split}_cells.npy`` for every stored split, from the records' seeds (ids only)."""
    for path in sorted(out.glob("*.jsonl")):
        t0 = time.perf_counter()
        cells = []
        for r in load_records(path):
            _, world, pose, _ = scene(r["seed"], worlds)
            cells.append(cell_labels(world, pose))
        np.save(out / f"{path.stem}_cells.npy", np.stack(cells))
        took = time.perf_counter() - t0
        print(f"{path.stem}: {len(cells)} cell maps in {took:.1f} s", flush=True)


def mentionable(item: SceneItem) -> bool:
    """Large enough to be named in the references (see ``MENTION_MIN_AREA``)."""
    return item.area >= (MARKER_MIN_AREA if item.kind == "marker" else MENTION_MIN_AREA)


def label(record: dict[str, Any], seen: list[SceneItem]) -> dict[str, Any]:
    """Add references, mentionable items and all visible items to a sample record."""
    items = [i for i in seen if mentionable(i)]
    return {
        **record,
        "refs": references(items, N_REFS, record["seed"]),
        "items": [asdict(i) for i in items],
        "seen": [asdict(i) for i in seen],
    }


def relabel(out: Path) -> None:
    """Rewrite the captions of stored splits from their stored scene graphs (no rendering)."""
    for path in sorted(out.glob("*.jsonl")):
        records = [label(r, items_of(r, "seen")) for r in load_records(path)]
        path.write_text("\n".join(json.dumps(r, separators=(",", ":")) for r in records) + "\n")
        print(f"{path.name}: {len(records)} records relabelled", flush=True)


def load_records(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def items_of(record: dict[str, Any], key: str = "items") -> list[SceneItem]:
    return [SceneItem(**d) for d in record[key]]


def write_split(out: Path, split: str, n: int, worlds: dict[str, World]) -> None:
    """``{split}.npz``, ``{split}.jsonl`` and the dense labels ``{split}_cells.npy``."""
    images = np.zeros((n, *INPUT_HW, 3), np.uint8)
    lines = []
    cells = []
    t0 = time.perf_counter()
    for i in range(n):
        seed = SEED_BASE[split] + i
        _, small, rec = make_sample(seed, worlds)
        images[i] = small
        lines.append(json.dumps(rec, separators=(",", ":")))
        _, world, pose, _ = scene(seed, worlds)
        cells.append(cell_labels(world, pose))
    np.savez_compressed(out / f"{split}.npz", images=images)
    (out / f"{split}.jsonl").write_text("\n".join(lines) + "\n")
    np.save(out / f"{split}_cells.npy", np.stack(cells))
    print(f"{split}: {n} images in {time.perf_counter() - t0:.1f} s", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("data/captions"))
    ap.add_argument("--train", type=int, default=4000)
    ap.add_argument("--val", type=int, default=300)
    ap.add_argument("--test", type=int, default=500)
    ap.add_argument("--train2", type=int, default=0, help="extra training images (own seeds)")
    ap.add_argument("--train3", type=int, default=0, help="more extra training images")
    ap.add_argument("--only", choices=sorted(SEED_BASE), help="write just this split")
    ap.add_argument(
        "--relabel", action="store_true", help="only rewrite the captions of stored splits"
    )
    ap.add_argument(
        "--cells", action="store_true", help="only (re)write the dense kind labels of every split"
    )
    args = ap.parse_args(argv)
    if args.relabel:
        relabel(args.out)
        return 0
    if args.cells:
        write_cells(args.out, {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")})
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    worlds = {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")}
    for split in ("train", "train2", "train3", "val", "test"):
        if (args.only is None or args.only == split) and getattr(args, split) > 0:
            write_split(args.out, split, getattr(args, split), worlds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
