"""The import graph of ``server``, ``drone`` and ``experiments``: no cycles, no upward imports.

Every import counts, at module level or inside a function, except those under
``if TYPE_CHECKING:`` (never run). A cycle makes the order of initialisation decide what works;
``drone`` (flying) never imports ``server`` (people and clients).
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("server", "drone", "experiments")
PRODUCT = ("server", "drone")  # what the wheel ships


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imports_of(path: Path, modules: set[str]) -> set[str]:
    """The project modules ``path`` imports when it runs."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()

    def resolve(target: str) -> None:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        if target and target != name:
            found.add(target)

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                for alias in child.names:
                    resolve(alias.name)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    anchor = package.split(".")
                    anchor = anchor[: len(anchor) - (child.level - 1)]
                    base = ".".join([*anchor, base] if base else anchor)
                for alias in child.names:
                    full = f"{base}.{alias.name}"
                    resolve(full if full in modules else base)
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return found


def import_graph() -> dict[str, set[str]]:
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")]
    modules = {module_name(p) for p in files}
    return {module_name(p): imports_of(p, modules) for p in files}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


@pytest.fixture(scope="module")
def project_graph() -> dict[str, set[str]]:
    """The import graph of ``server`` and ``drone``, walked once for this file's tests (the walk
    parses every file of both packages)."""
    return import_graph()


def test_no_import_cycles(project_graph: dict[str, set[str]]) -> None:
    graph = project_graph
    # A package's __init__ importing its own modules is not a cycle of the design.
    graph = {
        m: {d for d in deps if not (m == d.rpartition(".")[0] and graph.get(m) is not None)}
        for m, deps in graph.items()
    }
    assert cycles(graph) == []


def test_drone_never_imports_server(project_graph: dict[str, set[str]]) -> None:
    graph = project_graph
    upward = sorted(
        f"{m} -> {d}"
        for m, deps in graph.items()
        if m.startswith("drone")
        for d in deps
        if d.startswith("server")
    )
    assert upward == []


def top_level_imports(path: Path) -> set[str]:
    """The top-level names of the absolute imports ``path`` makes when it runs."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                found.update(alias.name.split(".")[0] for alias in child.names)
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                found.add(child.module.split(".")[0])
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return found


def test_product_never_imports_the_report_extra() -> None:
    """matplotlib is the ``report`` extra's, for the experiments (``experiments/``): a console
    or a vehicle is installed without it."""
    report = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = [d.split(">")[0].split("=")[0].split("[")[0].strip() for d in report["dependencies"]]
    assert "matplotlib" not in core
    assert any(d.startswith("matplotlib") for d in report["optional-dependencies"]["report"])
    users = sorted(
        module_name(p)
        for pkg in PRODUCT
        for p in (ROOT / pkg).rglob("*.py")
        if "matplotlib" in top_level_imports(p)
    )
    assert users == []


def test_product_imports_the_experiments_only_for_their_command() -> None:
    """``uav-console patrol`` runs the experiment; nothing else of the product depends on it."""
    graph = import_graph()
    users = sorted(
        f"{m} -> {d}"
        for m, deps in graph.items()
        if m.split(".")[0] in PRODUCT
        for d in deps
        if d.split(".")[0] == "experiments"
    )
    assert users == ["server.cli -> experiments.patrol.cli"]


def test_the_walker_sees_imports_inside_functions(tmp_path: Path) -> None:
    source = tmp_path / "server" / "x.py"
    source.parent.mkdir()
    source.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from server import y\n"
        "def f():\n    from server import z\n"
    )
    modules = {"server", "server.x", "server.y", "server.z"}
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        assert imports_of(source, modules) == {"server.z"}
    finally:
        ROOT = saved
