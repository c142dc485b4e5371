"""pyproject.toml's dependency bounds: each has a lower bound, and the lower bounds are tested.

`make test-lower` installs the lowest versions the bounds allow (uv's lowest-direct resolution)
and runs the suite on them with UAV_CONSOLE_LOWER_BOUNDS=1; there the last test checks that what
is installed is each bound itself, so a bound that cannot be installed as written (another
dependency needs more) fails here instead of passing untested.
"""

from __future__ import annotations

import os
import tomllib
from importlib.metadata import version
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
# The extras that `.[test]` installs (itself included): what `make test-lower` has.
TESTED_EXTRAS = ("speech", "captioner", "report", "test")


def requirements(extras: tuple[str, ...] | None = None) -> list[Requirement]:
    """The project's requirements and those of ``extras`` (all extras when None), not itself."""
    optional = PROJECT["optional-dependencies"]
    names = optional if extras is None else extras
    lines = [*PROJECT["dependencies"], *(r for e in names for r in optional[e])]
    return [r for r in map(Requirement, lines) if r.name != PROJECT["name"]]


def lower_bound(req: Requirement) -> str | None:
    """The version a ``>=``, ``==`` or ``~=`` specifier starts from (None without one)."""
    for spec in req.specifier:
        if spec.operator in (">=", "==", "~="):
            return spec.version
    return None


def test_every_dependency_has_a_lower_bound() -> None:
    missing = [str(r) for r in requirements() if lower_bound(r) is None]
    assert missing == []


def test_uvicorn_is_bounded_to_the_versions_its_guards_were_tested_on() -> None:
    """server/http/conn_guard.py and ws_guard.py subclass uvicorn's protocol classes."""
    (uvicorn,) = (r for r in requirements() if r.name == "uvicorn")
    assert any(s.operator in ("<", "<=", "==", "~=") for s in uvicorn.specifier), uvicorn
    assert version("uvicorn") in uvicorn.specifier


def test_ci_runs_lint_and_the_readme_test_command() -> None:
    """.ci/run: `make lint`, the README's `make test`, then `make test-lower` (the lower
    bounds), each run even if the one before it failed (``|| status=$?``)."""
    lines = [ln for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln.startswith("make ")]
    assert [ln.split("||")[0].strip() for ln in lines] == [
        "make lint",
        "make test",
        "make test-lower",
    ]
    assert all(ln.endswith("|| status=$?") for ln in lines)


@pytest.mark.skipif(
    os.environ.get("UAV_CONSOLE_LOWER_BOUNDS") != "1",
    reason="checks the lower-bounds install of `make test-lower` (UAV_CONSOLE_LOWER_BOUNDS=1)",
)
def test_the_lower_bounds_are_what_is_installed() -> None:
    """Each installed version is the bound's release (``>=4.9`` → a 4.9.x; ``>=3.0.1`` → 3.0.1)."""
    wrong = {
        r.name: (str(r.specifier), version(r.name))
        for r in requirements(TESTED_EXTRAS)
        if (low := lower_bound(r)) is not None
        and version(r.name) not in SpecifierSet(f"=={low}.*", prereleases=True)
    }
    assert wrong == {}
