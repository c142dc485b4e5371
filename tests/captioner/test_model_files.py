"""Missing, corrupt or mismatched model files: CaptionerUnavailable with a clear reason."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from server.captioner import Captioner, CaptionerUnavailable


@pytest.fixture
def copy(tmp_path: Path, model_dir: Path) -> Path:
    out = tmp_path / "model"
    out.mkdir()
    for name in ("encoder.onnx", "decoder.onnx", "vocab.json"):
        shutil.copy(model_dir / name, out / name)
    return out


def _missing(name: str) -> Callable[[Path], None]:
    return lambda d: (d / name).unlink()


def _bytes(name: str, data: bytes) -> Callable[[Path], None]:
    return lambda d: (d / name).write_bytes(data)


def _truncate(name: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        data = (d / name).read_bytes()
        (d / name).write_bytes(data[: len(data) // 2])

    return f


def _swap(d: Path) -> None:
    shutil.copy(d / "decoder.onnx", d / "encoder.onnx")


def _vocab(change: Callable[[dict], None]) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        data = json.loads((d / "vocab.json").read_text())
        change(data)
        (d / "vocab.json").write_text(json.dumps(data))

    return f


CASES = [
    (_missing("encoder.onnx"), r"encoder\.onnx is missing"),
    (_missing("decoder.onnx"), r"decoder\.onnx is missing"),
    (_missing("vocab.json"), r"vocab\.json is missing"),
    (_bytes("encoder.onnx", b"\x00\x01garbage" * 10), r"encoder\.onnx is not a loadable ONNX"),
    (_bytes("decoder.onnx", b""), r"decoder\.onnx is not a loadable ONNX"),
    (_truncate("decoder.onnx"), r"decoder\.onnx is not a loadable ONNX"),
    (_bytes("vocab.json", b"\xff\xfe{"), r"vocab\.json is not valid JSON"),
    (_swap, r"encoder\.onnx must have one input named 'image'"),
    (_vocab(lambda v: v["tokens"].append("zebra")), r"'logits' has \d+ columns but vocab"),
    (_vocab(lambda v: v.update(bos="<start>")), r"special token bos='<start>'"),
]


@pytest.mark.parametrize(("break_it", "reason"), CASES)
def test_broken_model_dir_says_why(
    copy: Path, break_it: Callable[[Path], None], reason: str
) -> None:
    Captioner.load(copy).close()  # the intact copy loads
    break_it(copy)
    with pytest.raises(CaptionerUnavailable, match=reason) as info:
        Captioner.load(copy)
    assert info.value.reason == str(info.value)


def test_model_dir_that_does_not_exist(tmp_path: Path) -> None:
    with pytest.raises(CaptionerUnavailable, match="missing"):
        Captioner.load(tmp_path / "nowhere")


def test_shipped_model_is_small(model_dir: Path) -> None:
    total = sum(
        (model_dir / n).stat().st_size for n in ("encoder.onnx", "decoder.onnx", "vocab.json")
    )
    assert total <= 10 * 1024 * 1024


def test_without_onnxruntime_the_reason_names_the_extra(model_dir: Path) -> None:
    """onnxruntime is the ``captioner`` extra: a console installed without it still starts and
    says how to get scene description."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['onnxruntime'] = None\n"
        "from server.captioner import load_captioner\n"
        f"print(load_captioner({str(model_dir)!r}).reason)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "uav-console[captioner]" in out.stdout
