"""Train the scene-region kind classifier (``server/captioner/scene.py``) on simulator renders.

Renders randomised scenes (``server.captioner.evalset.scene`` on its own seed range, randomised
objects only: the shipped worlds' layouts are never trained on), finds the regions of one paint
in each frame exactly as at run time, and labels each from the renderer's id buffer: the kind
of the object covering most of the region when the region has that object's paint, ``none``
otherwise (a part in another paint, floor, sky). Then fits a one-hidden-layer network (ReLU,
softmax) with full-batch Adam in numpy: seeded, single-threaded, exactly reproducible.

    .venv/bin/python tools/train_scene_regions.py --workers 2 --out models/captioner/regions.json

8000 scenes (about 33 000 regions); rendering and parsing take a few minutes of CPU per
thousand scenes, fitting a few more.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

# one BLAS thread: exactly reproducible sums, and no spinning threads on a shared machine
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drone.sim.world import load_world  # noqa: E402
from server.captioner.evalset import scene  # noqa: E402
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


def collect(n: int, start: int) -> tuple[np.ndarray, np.ndarray]:
    """Feature rows and kind labels of every region in ``n`` randomised scenes."""
    import cv2

    worlds = {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")}
    xs: list[tuple[float, ...]] = []
    ys: list[int] = []
    seed = start
    done = 0
    while done < n:
        seed += 1
        _, variant, world, pose, renderer = scene(seed, worlds)
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
    return np.asarray(xs, np.float64), np.asarray(ys, np.int64)


def train(
    x: np.ndarray, y: np.ndarray, hidden: int, steps: int, seed: int, l2: float = 1e-3
) -> dict[str, list[float] | list[list[float]]]:
    """One-hidden-layer softmax network, full-batch Adam (lr 0.01, L2 weight decay)."""
    rng = np.random.default_rng(seed)
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
    m = {p: np.zeros_like(v) for p, v in params.items()}
    v = {p: np.zeros_like(val) for p, val in params.items()}
    onehot = np.eye(k)[y]
    lr, b1, b2 = 0.01, 0.9, 0.999
    for t in range(1, steps + 1):
        h_pre = z @ params["w1"] + params["b1"]
        h = np.maximum(h_pre, 0.0)
        logits = h @ params["w2"] + params["b2"]
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        p /= p.sum(axis=1, keepdims=True)
        g_logits = (p - onehot) / n
        grads = {
            "w2": h.T @ g_logits + l2 * params["w2"],
            "b2": g_logits.sum(axis=0),
        }
        g_h = g_logits @ params["w2"].T * (h_pre > 0)
        grads["w1"] = z.T @ g_h + l2 * params["w1"]
        grads["b1"] = g_h.sum(axis=0)
        for name in params:
            m[name] = b1 * m[name] + (1 - b1) * grads[name]
            v[name] = b2 * v[name] + (1 - b2) * grads[name] ** 2
            mh = m[name] / (1 - b1**t)
            vh = v[name] / (1 - b2**t)
            params[name] -= lr * mh / (np.sqrt(vh) + 1e-8)
        if t % 500 == 0:
            loss = -np.mean(np.log(p[np.arange(n), y] + 1e-12))
            print(f"step {t}: loss {loss:.4f}, accuracy {np.mean(p.argmax(1) == y):.3f}")
    return {
        "mean": mean.tolist(),
        "scale": scale.tolist(),
        **{name: val.tolist() for name, val in params.items()},
    }


def _without_cache(argv: list[str] | None) -> list[str]:
    args = list(sys.argv[1:] if argv is None else argv)
    while "--cache" in args:
        i = args.index("--cache")
        del args[i : i + 2]
    return args


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scenes", type=int, default=8000)
    ap.add_argument("--hidden", type=int, default=64)
    ap.add_argument("--steps", type=int, default=1500)
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
        jobs = [(args.scenes // len(TRAIN_SEED_BASES), base) for base in TRAIN_SEED_BASES]
        if args.workers > 1:
            import multiprocessing

            with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
                parts = pool.starmap(collect, jobs)
        else:
            parts = [collect(*job) for job in jobs]
        x = np.concatenate([p[0] for p in parts])
        y = np.concatenate([p[1] for p in parts])
        if args.cache is not None:
            np.savez_compressed(args.cache, x=x, y=y)
    assert x.shape[1] == N_FEATURES, (x.shape, N_FEATURES)
    counts = {KINDS[i]: int(c) for i, c in enumerate(np.bincount(y, minlength=len(KINDS)))}
    took = time.perf_counter() - t0
    print(f"{len(y)} regions from {args.scenes} scenes in {took:.0f} s: {counts}")
    weights = train(x, y, args.hidden, args.steps, args.seed, args.l2)
    out = {
        "format": "uav-console-scene-regions/1",
        "kinds": list(KINDS),
        "features": N_FEATURES,
        "trained": {
            # the features cache only saves rendering again: it is left out of the command
            "command": " ".join(["tools/train_scene_regions.py", *_without_cache(argv)]),
            "scenes": args.scenes,
            "seed_bases": list(TRAIN_SEED_BASES),
            "regions": counts,
            "hidden": args.hidden,
            "steps": args.steps,
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
