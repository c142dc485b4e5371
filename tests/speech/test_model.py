"""Finding and verifying the model: the SHA-256 check is an error, never a silent fallback."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from server.speech import model
from server.speech.errors import ModelChecksumError, ModelMissing


def fake_model(directory: Path, content: bytes = b"not really a model") -> Path:
    directory.mkdir(parents=True)
    (directory / "model.bin").write_bytes(content)
    src = model.bundled_dir()
    for name in ("config.json", "tokenizer.json", "vocabulary.txt"):
        shutil.copy(src / name, directory / name)
    return directory


def test_bundled_model_is_found_and_verified() -> None:
    source = model.resolve(None)
    assert source.name == "tiny.en" and source.sha256 == model.BUNDLED_SHA256
    assert model.verify(source) == model.BUNDLED_SHA256


def test_a_substituted_model_bin_is_refused_with_both_digests(tmp_path: Path) -> None:
    d = fake_model(tmp_path / "m")
    source = model.ModelSource(d, "tiny.en", model.BUNDLED_SHA256)
    with pytest.raises(ModelChecksumError, match=model.BUNDLED_SHA256) as err:
        model.load_whisper(source, workers=1)
    assert model.file_sha256(d / "model.bin") in str(err.value)


def test_custom_directory_checked_against_its_sidecar_digest(tmp_path: Path) -> None:
    d = fake_model(tmp_path / "base.en")
    (d / "model.bin.sha256").write_text("0" * 64 + "  model.bin\n")
    with pytest.raises(ModelChecksumError):
        model.verify(model.resolve(d))
    (d / "model.bin.sha256").write_text(model.file_sha256(d / "model.bin") + "\n")
    assert model.verify(model.resolve(d))
    # An explicit digest (--asr-model-sha256) wins over the sidecar.
    with pytest.raises(ModelChecksumError):
        model.verify(model.resolve(d, "f" * 64))


def test_missing_things_are_named(tmp_path: Path) -> None:
    with pytest.raises(ModelMissing, match="does not exist"):
        model.verify(model.resolve(tmp_path / "nowhere"))
    d = tmp_path / "empty"
    d.mkdir()
    with pytest.raises(ModelMissing, match=r"model\.bin"):
        model.verify(model.resolve(d))


def test_a_corrupt_model_that_passes_no_check_fails_to_load_clearly(tmp_path: Path) -> None:
    d = fake_model(tmp_path / "junk", b"\x00" * 1000)
    with pytest.raises(ModelMissing, match="CTranslate2 cannot load"):
        model.load_whisper(model.resolve(d), workers=1)
