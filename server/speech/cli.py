"""``uav-console interpret --audio FILE.wav [FILE.wav ...]``: offline speech -> JSON lines.

One line per file, in order: ``{"file", "text", "confidence", "commands"}``; a file that cannot
be read or recognised gives ``{"file", "error"}`` and the run goes on; the exit status is 1 at
the end if any file failed, 2 if the model itself cannot be loaded (nothing is decoded then).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TextIO

from server.language.errors import GrammarError
from server.language.nlu import NLU, default_nlu
from server.speech.audio import read_wav
from server.speech.errors import AudioError, ModelError
from server.speech.service import SpeechConfig, SpeechService

MAX_FILE_BYTES = 64 * 1024 * 1024  # larger cannot be 30 s of 16-bit PCM; not read at all


def interpret_audio_main(
    files: list[str],
    stdout: TextIO,
    *,
    model_dir: Path | None = None,
    model_sha256: str | None = None,
    grammar_dir: Path | None = None,
    window_s: float = 0.0,
    beams: int = 0,
) -> int:
    """Recognise each file in turn (see the module docstring for the output)."""
    try:
        nlu = NLU(grammar_dir) if grammar_dir is not None else default_nlu()
        config = SpeechConfig(model_dir, model_sha256, workers=1, window_s=window_s, beams=beams)
        service = SpeechService(config, nlu)
        recognizer = service.load()
    except (GrammarError, ModelError) as exc:
        print(f"uav-console interpret: {exc}", file=sys.stderr)
        return 2
    status = 0
    for name in files:
        out: dict[str, object] = {"file": name}
        try:
            path = Path(name)
            if path.is_file() and path.stat().st_size > MAX_FILE_BYTES:
                raise AudioError(f"{path.stat().st_size} bytes: too large for 30 s of audio")
            samples = read_wav(path.read_bytes())
            rec = recognizer.recognize(samples)
            out.update(text=rec.text, confidence=round(rec.confidence, 4), commands=rec.commands)
            if rec.heard != rec.text:
                out["heard"] = rec.heard
        except (OSError, AudioError) as exc:
            out["error"] = _describe(exc)
            status = 1
        stdout.write(json.dumps(out) + "\n")
        stdout.flush()
    return status


def _describe(exc: Exception) -> str:
    if isinstance(exc, FileNotFoundError):
        return "no such file"
    if isinstance(exc, IsADirectoryError):
        return "is a directory"
    if isinstance(exc, PermissionError):
        return "permission denied"
    return str(exc)
