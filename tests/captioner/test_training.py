"""The dataset generator and the trainer, end to end on a tiny dataset.

The generator needs only the simulator; the trainer needs the optional ``[train]`` extra (torch,
onnx) and is skipped where it is not installed (CI installs only ``[test]``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from server.captioner import Captioner
from server.captioner.references import SceneItem, mentions
from tools import make_caption_dataset as gen


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("captions")
    assert gen.main(["--out", str(out), "--train", "24", "--val", "6", "--test", "0"]) == 0
    return out


def test_generator_writes_images_references_and_cell_labels(tiny: Path) -> None:
    images = np.load(tiny / "train.npz")["images"]
    assert images.shape == (24, *gen.INPUT_HW, 3) and images.dtype == np.uint8
    records = gen.load_records(tiny / "train.jsonl")
    assert len(records) == 24
    cells = np.load(tiny / "train_cells.npy")
    assert cells.shape == (24, 2, *gen.CELL_GRID)
    assert not (tiny / "test.npz").exists()
    for rec in records:
        assert len(rec["refs"]) == gen.N_REFS and len(set(rec["refs"])) > 1  # varied wording
        named = {m.kind for r in rec["refs"] for m in mentions(r, gen.KINDS, gen.COLOUR_NAMES)}
        seen = {SceneItem(**it).kind for it in rec["seen"]}
        assert named <= seen, (rec["refs"], seen)  # references never name what is not there
    assert any(rec["items"] for rec in records)


def test_generator_is_reproducible_from_its_seeds(tiny: Path, tmp_path: Path) -> None:
    assert gen.main(["--out", str(tmp_path), "--only", "val", "--val", "6"]) == 0
    again = np.load(tmp_path / "val.npz")["images"]
    assert np.array_equal(again, np.load(tiny / "val.npz")["images"])
    assert (tmp_path / "val.jsonl").read_text() == (tiny / "val.jsonl").read_text()
    train = np.load(tiny / "train.npz")["images"]
    assert not any(np.array_equal(v, t) for v in again for t in train)  # disjoint seeds


def test_trainer_exports_a_model_the_runtime_loads(tiny: Path, tmp_path: Path) -> None:
    pytest.importorskip("torch")
    pytest.importorskip("onnx")
    from tools import train_captioner

    out = tmp_path / "model"
    args = ["--data", str(tiny), "--out", str(out), "--epochs", "2", "--batch", "8"]
    assert train_captioner.main(args) == 0
    meta = json.loads((out / "training.json").read_text())
    assert meta["seed"] == 7 and meta["train_images"] == 24 and len(meta["history"]) == 2
    cap = Captioner.load(out)
    try:
        frame = np.load(tiny / "val.npz")["images"][0]
        c = cap.caption(frame, beam=3)
        assert c.text.endswith(".") and all(t in cap.vocab.tokens for t in c.tokens)
        assert len(cap.vocab) == meta["vocab"]
    finally:
        cap.close()
    # Same seed, same data: the same weights, so the same ONNX files.
    out2 = tmp_path / "again"
    assert train_captioner.main([*args[:2], "--out", str(out2), *args[4:]]) == 0
    for name in ("encoder.onnx", "decoder.onnx", "vocab.json"):
        assert (out2 / name).read_bytes() == (out / name).read_bytes(), name
