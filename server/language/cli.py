"""``uav-console interpret [TEXT]``: the NLU alone, text in, JSON commands out."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TextIO

from server.language.errors import GrammarError
from server.language.nlu import NLU, default_nlu


def interpret_main(
    argv: list[str] | None, stdin: TextIO, stdout: TextIO, grammar_dir: Path | None = None
) -> int:
    """One text -> one JSON object ``{"text": ..., "commands": [...]}``.

    ``argv`` holds the words of TEXT (joined by spaces). With no TEXT, reads one utterance per
    line from ``stdin`` and prints one JSON object per line (blank lines give ``[]`` too).

    Returns:
        0, or 2 if the grammar cannot be loaded (the error, naming file/line/rule, on stderr).
    """
    try:
        nlu = NLU(grammar_dir) if grammar_dir is not None else default_nlu()
    except GrammarError as exc:
        print(f"uav-console interpret: {exc}", file=sys.stderr)
        return 2
    if argv:
        _emit(nlu, " ".join(argv), stdout)
        return 0
    for line in stdin:
        _emit(nlu, line.rstrip("\r\n"), stdout)
    return 0


def _emit(nlu: NLU, text: str, stdout: TextIO) -> None:
    stdout.write(json.dumps({"text": text, "commands": nlu.interpret(text)}) + "\n")
    stdout.flush()
