"""Checks over the product's source (``server``, ``drone``): code and comments say what is true
now (git and the CHANGELOG hold history), a function over the complexity limit says why, and
each class name means one thing."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("server", "drone")

# "issue 14", "issues 13", "Issue #8": a tracker reference, which says nothing to a reader of the
# code; the reason it stood for (slowloris, a benchmark, a test) is what belongs there.
ISSUE_REF = re.compile(r"\b[Ii]ssues? #?\d+")


def product_files() -> list[Path]:
    return sorted(p for pkg in PRODUCT for p in (ROOT / pkg).rglob("*.py"))


def prose(source: str) -> Iterator[tuple[int, str]]:
    """``(line, text)`` of every comment and every bare string statement (docstrings of modules,
    classes and functions, and those under an assignment): the text written for a reader, not
    the strings the program uses (replies, error texts)."""
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string
    for node in ast.walk(ast.parse(source)):
        if (
            isinstance(node, ast.Expr)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            for n, line in enumerate(node.value.value.splitlines()):
                yield node.lineno + n, line


def issue_references(source: str) -> list[tuple[int, str]]:
    return sorted((n, text.strip()) for n, text in prose(source) if ISSUE_REF.search(text))


def test_issue_references_are_found_in_comments_and_docstrings_only() -> None:
    source = (
        '"""Module (issue 14)."""\n'
        "X = 1  # a cap (Issue #8)\n"
        'Y = 2\n"""Y\'s docstring, issues 13 and 15."""\n'
        "def f() -> str:\n"
        '    """A function."""\n'
        '    return "the user-facing issue 3 text stays"\n'
        "# this issue is fixed by design, tissue 4 is not a reference\n"
    )
    assert [n for n, _ in issue_references(source)] == [1, 2, 4]


def test_no_issue_references_in_the_product() -> None:
    """A tracker number in a comment tells a reader nothing the code does not; say the reason
    (the attack, the benchmark, the test) instead."""
    found = [
        f"{path.relative_to(ROOT)}:{n}: {text}"
        for path in product_files()
        for n, text in issue_references(path.read_text())
    ]
    assert not found, "issue references in comments or docstrings:\n" + "\n".join(found)


# A function that ruff's C901 would refuse (complexity over ``max-complexity`` in pyproject.toml)
# carries ``noqa: C901`` on its ``def`` and a "Complexity:" paragraph in its docstring that says
# why it is one function.
NOQA_C901 = re.compile(r"#\s*noqa:[^#]*\bC901\b")
REASON = re.compile(r"^Complexity: \S+(?: \S+){4,}", re.MULTILINE)


def complexity_exemptions(source: str) -> tuple[list[tuple[int, str, bool]], list[int]]:
    """``(line, function, says why)`` of each function whose header carries ``noqa: C901``, and
    the lines of such comments on no function's header."""
    marks = {
        tok.start[0]
        for tok in tokenize.generate_tokens(io.StringIO(source).readline)
        if tok.type == tokenize.COMMENT and NOQA_C901.search(tok.string)
    }
    found: list[tuple[int, str, bool]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            header = set(range(node.lineno, node.body[0].lineno))
            if header & marks:
                marks -= header
                doc = ast.get_docstring(node) or ""
                found.append((node.lineno, node.name, REASON.search(doc) is not None))
    return sorted(found), sorted(marks)


def test_complexity_exemptions_are_found_with_their_reasons() -> None:
    source = (
        "def a(  # noqa: C901\n    x: int,\n) -> None:\n"
        '    """A.\n\n    Complexity: one branch per message type, flat on purpose."""\n'
        "def b() -> None:  # noqa: E501, C901\n"
        '    """B, complex (no reason given)."""\n'
        "def c() -> None:  # noqa: C901\n"
        '    """C.\n\n    Complexity: yes."""\n'
        "X = 1  # noqa: C901\n"
    )
    assert complexity_exemptions(source) == (
        [(1, "a", True), (7, "b", False), (9, "c", False)],
        [13],
    )


def test_every_complexity_exemption_says_why() -> None:
    """``noqa: C901`` silences the complexity limit; the docstring's "Complexity:" paragraph is
    what tells the next reader why the function is still one function (a table of closures, a
    schema read in its own order, one branch per message type)."""
    silent, stray = [], []
    for path in product_files():
        functions, marks = complexity_exemptions(path.read_text())
        name = path.relative_to(ROOT)
        silent += [f"{name}:{n} {f}" for n, f, says_why in functions if not says_why]
        stray += [f"{name}:{n}" for n in marks]
    assert not silent, f"noqa: C901 without a 'Complexity:' reason in the docstring: {silent}"
    assert not stray, f"noqa: C901 on no function's header: {stray}"


# Class names defined in more than one module of the product, each with why it is one thing under
# one name. Besides these: names private to their module (``_Link``) and the exceptions of each
# package's ``errors.py`` (STYLE: one exception tree per package, caught by its package's name).
SAME_THING = {
    "Auth": "the ``auth`` op of two wire protocols (rosbridge, the safety door), named after the "
    "op as its sibling ops are",
    "LinkLost": "the link-lost event of the AR.Drone and the MAVLink protocol cores, each with "
    "what its protocol knows",
    "LinkRestored": "the link-restored event of the AR.Drone and the MAVLink protocol cores",
}


def class_modules(files: list[Path]) -> dict[str, list[str]]:
    """Class name → the modules (paths relative to ROOT) defining a class of that name."""
    found: defaultdict[str, list[str]] = defaultdict(list)
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                found[node.name].append(path.relative_to(ROOT).as_posix())
    return found


def name_clashes(found: dict[str, list[str]]) -> dict[str, list[str]]:
    """The names defined twice or more, less the module-private ones and each package's
    ``errors.py`` exceptions."""
    return {
        name: paths
        for name, paths in sorted(found.items())
        if len(paths) > 1
        and not name.startswith("_")
        and not all(p.endswith("/errors.py") for p in paths)
    }


def test_name_clashes_skip_private_names_and_exception_trees() -> None:
    found = {
        "Telemetry": ["drone/bus/payloads.py", "drone/mavlink/gcs/events.py"],
        "FrameError": ["drone/mavlink/errors.py", "server/rosbridge/errors.py"],
        "CommandExpired": ["server/vehicles/deadlines.py", "server/vehicles/errors.py"],
        "_Udp": ["drone/mavlink/driver.py", "drone/mavlink/simserver.py"],
        "Vehicle": ["drone/vehicle.py"],
    }
    assert sorted(name_clashes(found)) == ["CommandExpired", "Telemetry"]


def test_one_name_per_class() -> None:
    """Two classes under one name make a reader (and an import) pick the wrong one: a name
    means one thing across ``server`` and ``drone``."""
    clashes = name_clashes(class_modules(product_files()))
    unexplained = {n: p for n, p in clashes.items() if n not in SAME_THING}
    assert not unexplained, f"class names defined in several modules: {unexplained}"
    assert sorted(set(SAME_THING) - set(clashes)) == [], "SAME_THING: names one module defines"


def test_no_issue_references_in_the_page_and_the_docs() -> None:
    """The page's scripts and the user docs (``docs/``) say what is true now, as the code does;
    history is the CHANGELOG's."""
    files = sorted(
        [
            *(ROOT / "web").rglob("*.js"),
            *(ROOT / "web").rglob("*.html"),
            *(ROOT / "docs").glob("*.md"),
        ]
    )
    found = [
        f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
        for path in files
        if "vendor" not in path.parts
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if ISSUE_REF.search(line)
    ]
    assert not found, "issue references:\n" + "\n".join(found)
