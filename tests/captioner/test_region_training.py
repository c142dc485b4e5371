"""The scene-region classifier's trainer: cluttered rooms, chunked rendering, mini-batches.

``tools/train_scene_regions.py`` renders randomised scenes (and cluttered rooms) on seed ranges
of its own and fits the classifier that ``server/captioner/scene.py`` loads; these tests run it
on a handful of scenes.
"""

from __future__ import annotations

import json
import math
import random
import sys
from pathlib import Path

import numpy as np
import pytest

from drone.sim.world import World
from server.captioner.scene import KINDS, N_FEATURES, RegionClassifier

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import train_scene_regions as trainer


def test_cluttered_rooms_are_reproducible_inside_the_room_and_apart(indoor: World) -> None:
    b = indoor.bounds
    tables_with_chairs = 0
    for seed in range(6_040_001, 6_040_041):
        objects = trainer.room_objects(indoor, random.Random(seed))
        assert objects == trainer.room_objects(indoor, random.Random(seed))
        assert 1 <= len(objects) <= 15, len(objects)
        standing = [o for o in objects if o.kind not in ("door", "window")]
        for o in objects:
            x, y, _ = o.position
            assert b.x_min <= x <= b.x_max and b.y_min <= y <= b.y_max, o
        for i, a in enumerate(standing):
            for c in standing[i + 1 :]:
                gap = math.dist(a.position[:2], c.position[:2])
                assert gap > 0.6, (seed, a, c)
        tables = [o for o in objects if o.kind == "table"]
        for t in tables[:1]:
            near = [
                o
                for o in objects
                if o.kind == "chair" and math.dist(o.position[:2], t.position[:2]) <= 1.0
            ]
            for chair in near:  # each chair of the group faces its table
                to_table = math.atan2(
                    t.position[1] - chair.position[1], t.position[0] - chair.position[0]
                )
                off = (chair.yaw_rad - to_table + math.pi) % (2 * math.pi) - math.pi
                assert abs(off) < 1e-6, (seed, chair, t)
            tables_with_chairs += bool(near)
    assert tables_with_chairs >= 10


def test_chunked_rendering_covers_the_same_scenes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(trainer, "CHUNK", 2)
    jobs = trainer._chunks(4, trainer.TRAIN_SEED_BASES[0], 2)
    assert [(n, start) for n, start, _ in jobs] == [
        (2, trainer.TRAIN_SEED_BASES[0]),
        (2, trainer.TRAIN_SEED_BASES[0] + 4),
    ]
    whole_x, whole_y = trainer.collect(4, trainer.TRAIN_SEED_BASES[0])
    parts = [trainer.collect(*job) for job in jobs]
    np.testing.assert_array_equal(whole_x, np.concatenate([p[0] for p in parts]))
    np.testing.assert_array_equal(whole_y, np.concatenate([p[1] for p in parts]))
    rooms = trainer._chunks(3, trainer.ROOM_SEED_BASE, 1, rooms=True)
    assert rooms == [(2, trainer.ROOM_SEED_BASE, True), (1, trainer.ROOM_SEED_BASE + 2, True)]


def _blobs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y = rng.integers(0, 3, n)
    x = rng.normal(0.0, 0.3, (n, N_FEATURES))
    x[np.arange(n), y] += 2.0
    return x, y


def test_mini_batch_training_fits_and_is_reproducible() -> None:
    x, y = _blobs(600, 1)
    first = trainer.train(x, y, hidden=8, steps=300, seed=3, batch=64)
    again = trainer.train(x, y, hidden=8, steps=300, seed=3, batch=64)
    assert first == again
    w = {k: np.asarray(v) for k, v in first.items()}
    clf = RegionClassifier(w["mean"], w["scale"], w["w1"], w["b1"], w["w2"], w["b2"])
    tx, ty = _blobs(300, 2)
    accuracy = float(np.mean(clf.probs(tx).argmax(axis=1) == ty))
    assert accuracy > 0.95, accuracy


def test_trainer_writes_a_classifier_the_runtime_loads(tmp_path: Path) -> None:
    out = tmp_path / "regions.json"
    argv = ["--scenes", "4", "--rooms", "2", "--steps", "20", "--batch", "16", "--hidden", "8"]
    assert trainer.main([*argv, "--out", str(out)]) == 0
    clf = RegionClassifier.load(out)
    assert clf.probs(np.zeros((1, N_FEATURES))).shape == (1, len(KINDS))
    trained = json.loads(out.read_text())["trained"]
    assert trained["rooms"] == 2 and trained["batch"] == 16
    assert trained["room_seed_base"] == trainer.ROOM_SEED_BASE
