"""Where the shipped data lives: grammars, worlds, the web console and the captioner model.

A source checkout (and an editable install) reads it from the repository; an installed wheel
(``pip install .``, the Docker image) has it under ``<prefix>/share/uav-console``, where the
``data-files`` table of ``pyproject.toml`` puts it.
"""

from __future__ import annotations

import site
import sys
import sysconfig
from pathlib import Path

SOURCE_ROOT = Path(__file__).resolve().parents[1]
"""The repository when running from a checkout; site-packages when installed from a wheel."""

SHARE_NAME = "uav-console"


def data_roots() -> list[Path]:
    """Places to look, in order: the checkout, then the install prefixes (system, venv, user)."""
    roots = [SOURCE_ROOT] if (SOURCE_ROOT / "pyproject.toml").is_file() else []
    prefixes = (sysconfig.get_path("data"), sys.prefix, site.getuserbase())
    for prefix in dict.fromkeys(prefixes):
        roots.append(Path(prefix) / "share" / SHARE_NAME)
    return roots


def share_dir(name: str) -> Path:
    """The shipped directory ``name`` (``grammars``, ``worlds``, ``web``, ``models/captioner``).

    When it is nowhere, the checkout's path is returned, so the caller's "missing" error names
    a path a developer recognises.
    """
    for root in data_roots():
        if (root / name).is_dir():
            return root / name
    return SOURCE_ROOT / name
