"""Checks over the product's source (``server``, ``drone``): code and comments say what is true
now (git and the CHANGELOG hold history), a function over the complexity limit says why, and
each class name means one thing."""

from __future__ import annotations

import ast
import io
import re
import tokenize
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
