"""Train the scene-region kind classifier (``server/captioner/scene.py``) on simulator renders.

Renders randomised scenes (``server.captioner.evalset.scene`` on its own seed range, randomised
objects only: the shipped worlds' layouts are never trained on) and, with ``--rooms``, cluttered
rooms (:func:`room_scene`), finds the regions of one paint in each frame exactly as at run time,
and labels each from the renderer's id buffer: the kind of the object covering most of the
region when the region has that object's paint, ``none`` otherwise (a part in another paint,
floor, sky). Then fits a one-hidden-layer network (ReLU, softmax) with Adam in numpy, full-batch
or on mini-batches (``--batch``), from scratch or from earlier weights (``--init``): seeded,
single-threaded, exactly reproducible. How the shipped file was made: models/captioner/MODEL.md.

    .venv/bin/python tools/train_scene_regions.py --workers 2 --out models/captioner/regions.json

8000 scenes (about 33 000 regions), 4000 rooms about 40 000 more; rendering and parsing take
a few minutes of CPU per thousand scenes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import sys
import time
from pathlib import Path

# one BLAS thread: exactly reproducible sums, and no spinning threads on a shared machine
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drone.sim.camera import Renderer  # noqa: E402
from drone.sim.world import COLOURS, SceneObject, World, load_world  # noqa: E402
from server.captioner.evalset import _PALETTE, _SIZES, Variant, _pose, scene  # noqa: E402
from server.captioner.scene import (  # noqa: E402
    KINDS,
    N_FEATURES,
    WORK_H,
    WORK_W,
    parse,
)

TRAIN_SEED_BASES = (6_000_000, 6_020_000)
"""Training scenes: seed ranges of their own (half the scenes from each, rendered in parallel
with ``--workers 2``), disjoint from the held-out set (3 000 000+) and its tuning twin."""
ROOM_SEED_BASE = 6_040_000
"""Cluttered rooms (``--rooms``): a seed range of their own, disjoint from the others."""
_ROOM_KINDS = ("chair", "table", "person", "plant", "box", "sofa", "shelf", "lamp")
_WALL_KINDS = ("sofa", "shelf", "lamp", "plant", "box")
_ROOM_PALETTE = (*_PALETTE, "white", "grey", "brown")
"""Furniture is often white, grey or brown: those paints are drawn twice as often here."""


def room_objects(world: World, rng: random.Random) -> tuple[SceneObject, ...]:
    """A cluttered room: up to 15 objects, chairs around a table, furniture against the walls,
    0.6 m apart (the randomised scenes of ``server.captioner.evalset`` hold 1–6 objects 0.9 m
    apart in the open, so kinds are rarely seen side by side, occluded or close up)."""
    b = world.bounds
    out: list[SceneObject] = []

    def add(kind: str, colour: str, x: float, y: float, z: float, yaw: float) -> None:
        w, d, h = _SIZES[kind]
        k = rng.uniform(0.8, 1.25)
        size = (w * k, d, h * k) if kind in ("door", "window") else (w * k, d * k, h * k)
        name = f"{kind}{len(out)}"
        out.append(SceneObject(name, kind, colour, COLOURS[colour], (x, y, z), yaw, size))

    def free(x: float, y: float, gap: float = 0.6) -> bool:
        return all(
            math.hypot(x - o.position[0], y - o.position[1]) > gap
            for o in out
            if o.kind not in ("door", "window")
        )

    for _ in range(rng.choice((0, 1, 2))):
        kind = rng.choice(("door", "window"))
        side = rng.randrange(4)
        along = rng.uniform(0.8, (b.x_max if side < 2 else b.y_max) - 0.8)
        x, y, yaw = (
            (along, b.y_min + 0.03, math.pi / 2),
            (along, b.y_max - 0.03, -math.pi / 2),
            (b.x_min + 0.03, along, 0.0),
            (b.x_max - 0.03, along, math.pi),
        )[side]
        z = 0.0 if kind == "door" else rng.uniform(0.8, 1.1)
        colour = "light blue" if kind == "window" else rng.choice(_ROOM_PALETTE)
        add(kind, colour, x, y, z, yaw)
    if rng.random() < 0.6:  # a table with chairs round it, facing it
        tx = rng.uniform(b.x_min + 1.5, b.x_max - 1.5)
        ty = rng.uniform(b.y_min + 1.5, b.y_max - 1.5)
        add("table", rng.choice(_ROOM_PALETTE), tx, ty, 0.0, rng.choice((0.0, math.pi / 2)))
        chair = rng.choice(_ROOM_PALETTE)
        for a in rng.sample((0.0, math.pi / 2, math.pi, -math.pi / 2), rng.randint(1, 4)):
            r = rng.uniform(0.75, 1.0)
            colour = chair if rng.random() < 0.7 else rng.choice(_ROOM_PALETTE)
            add("chair", colour, tx + r * math.cos(a), ty + r * math.sin(a), 0.0, a + math.pi)
    for _ in range(rng.randint(4, 8)):
        kind = rng.choice(_ROOM_KINDS)
        for _ in range(20):
            if kind in _WALL_KINDS and rng.random() < 0.6:  # against a wall, facing the room
                side = rng.randrange(4)
                x = rng.uniform(b.x_min + 0.5, b.x_max - 0.5)
                y = rng.uniform(b.y_min + 0.5, b.y_max - 0.5)
                x, y, yaw = (
                    (x, b.y_min + 0.45, math.pi / 2),
                    (x, b.y_max - 0.45, -math.pi / 2),
                    (b.x_min + 0.45, y, 0.0),
                    (b.x_max - 0.45, y, math.pi),
                )[side]
            else:
                x = rng.uniform(b.x_min + 0.5, b.x_max - 0.5)
                y = rng.uniform(b.y_min + 0.5, b.y_max - 0.5)
                yaw = rng.uniform(-math.pi, math.pi)
            if free(x, y):
                add(kind, rng.choice(_ROOM_PALETTE), x, y, 0.0, yaw)
                break
    return tuple(out)


def room_scene(
    seed: int, worlds: dict[str, World]
) -> tuple[str, Variant, World, tuple[float, float, float, float, float, float], Renderer]:
    """A cluttered indoor scene (:func:`room_objects`), posed and lit as ``evalset.scene``."""
    rng = random.Random(seed)
    world = worlds["indoor"].with_objects(room_objects(worlds["indoor"], rng))
    renderer = Renderer(
        world,
        seed=seed,
        brightness=rng.uniform(0.7, 1.3),
        noise_sigma=rng.uniform(0.0, 4.0),
        vignette=rng.uniform(0.0, 25.0),
    )
    return "indoor", "random", world, _pose(world, rng), renderer


def collect(n: int, start: int, rooms: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Feature rows and kind labels of every region in ``n`` randomised scenes (``rooms``:
    cluttered rooms, :func:`room_scene`)."""
    import cv2

    worlds = {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")}
    xs: list[tuple[float, ...]] = []
    ys: list[int] = []
    seed = start
    done = 0
    while done < n:
        seed += 1
        _, variant, world, pose, renderer = (room_scene if rooms else scene)(seed, worlds)
        if variant != "random":
            continue
        done += 1
        frame = renderer.render(pose, frame=seed)
        if seed % 3 == 0:  # some frames through JPEG, as the video path delivers them
            _, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 60 + seed % 31])
            frame = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        ids = renderer.render_ids(pose, WORK_W / frame.shape[1])
        assert ids.shape == (WORK_H, WORK_W)
        colours = [o.colour for o in world.objects]
        result = parse(frame)
        for region, mask in zip(result.regions, result.masks, strict=True):
            under = ids[mask]
            counts = np.bincount(under.astype(np.int64), minlength=len(world.objects) + 1)
            counts[0] = 0
            counts[len(world.objects) + 1 :] = 0
            k = int(counts.argmax())
            label = 0
            if k > 0 and counts[k] >= 0.5 * under.size and colours[k - 1] == region.colour:
                label = KINDS.index(world.objects[k - 1].kind)
            xs.append(region.features)
            ys.append(label)
    return np.asarray(xs, np.float64).reshape(-1, N_FEATURES), np.asarray(ys, np.int64)


def train(
    x: np.ndarray,
    y: np.ndarray,
    hidden: int,
    steps: int,
    seed: int,
    l2: float = 1e-3,
    batch: int = 0,
    init: dict[str, list[float] | list[list[float]]] | None = None,
    lr0: float = 0.01,
) -> dict[str, list[float] | list[list[float]]]:
    """One-hidden-layer softmax network, Adam (rate ``lr0``, L2 weight decay): full-batch, or
    with ``batch`` > 0 on seeded mini-batches with the rate decaying (cosine) to a tenth, which
    fits many regions at a fraction of the arithmetic. ``init``: weights (and standardisation)
    to start from, as written by this tool (``hidden`` is then theirs)."""
    rng = np.random.default_rng(seed)
    if init is not None:
        mean, scale = np.asarray(init["mean"], np.float64), np.asarray(init["scale"], np.float64)
    else:
        mean = x.mean(axis=0)
        scale = x.std(axis=0) + 1e-6
    z = (x - mean) / scale
    n, d = z.shape
    k = len(KINDS)
    params = {
        "w1": rng.normal(0, np.sqrt(2.0 / d), (d, hidden)),
        "b1": np.zeros(hidden),
        "w2": rng.normal(0, np.sqrt(1.0 / hidden), (hidden, k)),
        "b2": np.zeros(k),
    }
    if init is not None:
        params = {name: np.asarray(init[name], np.float64) for name in params}
    m = {p: np.zeros_like(v) for p, v in params.items()}
    v = {p: np.zeros_like(val) for p, val in params.items()}
    onehot = np.eye(k)[y]
    b1, b2 = 0.9, 0.999
    order = rng.permutation(n)
    at = 0
    for t in range(1, steps + 1):
        if batch > 0:
            if at + batch > n:
                order, at = rng.permutation(n), 0
            rows = order[at : at + batch]
            at += batch
            zb, yb = z[rows], onehot[rows]
            lr = lr0 * (0.1 + 0.45 * (1.0 + np.cos(np.pi * t / steps)))
        else:
            zb, yb, lr = z, onehot, lr0
        h_pre = zb @ params["w1"] + params["b1"]
        h = np.maximum(h_pre, 0.0)
        logits = h @ params["w2"] + params["b2"]
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        p /= p.sum(axis=1, keepdims=True)
        g_logits = (p - yb) / len(zb)
        grads = {
            "w2": h.T @ g_logits + l2 * params["w2"],
            "b2": g_logits.sum(axis=0),
        }
        g_h = g_logits @ params["w2"].T * (h_pre > 0)
        grads["w1"] = zb.T @ g_h + l2 * params["w1"]
        grads["b1"] = g_h.sum(axis=0)
        for name in params:
            m[name] = b1 * m[name] + (1 - b1) * grads[name]
            v[name] = b2 * v[name] + (1 - b2) * grads[name] ** 2
            mh = m[name] / (1 - b1**t)
            vh = v[name] / (1 - b2**t)
            params[name] -= lr * mh / (np.sqrt(vh) + 1e-8)
        if t % 500 == 0:
            yt = yb.argmax(axis=1)
            loss = -np.mean(np.log(p[np.arange(len(yt)), yt] + 1e-12))
            print(f"step {t}: loss {loss:.4f}, accuracy {np.mean(p.argmax(1) == yt):.3f}")
    return {
        "mean": mean.tolist(),
        "scale": scale.tolist(),
        **{name: val.tolist() for name, val in params.items()},
    }


CHUNK = 500
"""Scenes rendered per job (the same scenes whatever the number of workers)."""


def _chunks(
    n: int, base: int, seeds_per_scene: int, rooms: bool = False
) -> list[tuple[int, int, bool]]:
    """``collect`` jobs for ``n`` scenes from ``base`` on, ``CHUNK`` at a time: a randomised
    scene is every second seed (``evalset.scene``), a cluttered room every seed."""
    return [(min(CHUNK, n - k), base + k * seeds_per_scene, rooms) for k in range(0, n, CHUNK)]


def _without_cache(argv: list[str] | None) -> list[str]:
    args = list(sys.argv[1:] if argv is None else argv)
    while "--cache" in args:
        i = args.index("--cache")
        del args[i : i + 2]
    return args


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scenes", type=int, default=8000)
    ap.add_argument("--rooms", type=int, default=0, help="cluttered rooms besides the scenes")
    ap.add_argument("--hidden", type=int, default=64)
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=0, help="mini-batch size (0: full batch)")
    ap.add_argument("--lr", type=float, default=0.01, help="Adam's rate (its start, in batches)")
    ap.add_argument("--init", type=Path, help="start from these weights (a regions.json)")
    ap.add_argument("--l2", type=float, default=0.003)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--workers", type=int, default=1, help="render the seed ranges in parallel")
    ap.add_argument("--out", type=Path, default=Path("models/captioner/regions.json"))
    ap.add_argument("--cache", type=Path, help="keep the rendered features here (npz)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.cache is not None and args.cache.exists():
        data = np.load(args.cache)
        x, y = data["x"], data["y"]
    else:
        jobs = [
            *(job for base in TRAIN_SEED_BASES for job in _chunks(args.scenes // 2, base, 2)),
            *_chunks(args.rooms, ROOM_SEED_BASE, 1, rooms=True),
        ]
        if args.workers > 1:
            import multiprocessing

            with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
                parts = pool.starmap(collect, jobs, chunksize=1)
        else:
            parts = [collect(*job) for job in jobs]
        x = np.concatenate([p[0] for p in parts])
        y = np.concatenate([p[1] for p in parts])
        if args.cache is not None:
            np.savez_compressed(args.cache, x=x, y=y)
    assert x.shape[1] == N_FEATURES, (x.shape, N_FEATURES)
    counts = {KINDS[i]: int(c) for i, c in enumerate(np.bincount(y, minlength=len(KINDS)))}
    took = time.perf_counter() - t0
    scenes = args.scenes + args.rooms
    print(f"{len(y)} regions from {scenes} scenes in {took:.0f} s: {counts}")
    init = json.loads(args.init.read_text()) if args.init is not None else None
    hidden = len(init["b1"]) if init is not None else args.hidden
    weights = train(x, y, hidden, args.steps, args.seed, args.l2, args.batch, init, args.lr)
    out = {
        "format": "uav-console-scene-regions/1",
        "kinds": list(KINDS),
        "features": N_FEATURES,
        "trained": {
            # the features cache only saves rendering again: it is left out of the command
            "command": " ".join(["tools/train_scene_regions.py", *_without_cache(argv)]),
            "scenes": args.scenes,
            "seed_bases": list(TRAIN_SEED_BASES),
            "rooms": args.rooms,
            "room_seed_base": ROOM_SEED_BASE,
            "regions": counts,
            "hidden": hidden,
            "steps": args.steps,
            "batch": args.batch,
            "lr": args.lr,
            "init": None if init is None else {"file": args.init.name, **init["trained"]},
            "l2": args.l2,
            "seed": args.seed,
        },
        **weights,
    }
    args.out.write_text(json.dumps(out, separators=(",", ":")) + "\n")
    print(f"wrote {args.out} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
