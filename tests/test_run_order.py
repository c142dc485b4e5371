"""The order ``tests/conftest.py`` gives an xdist worker's collection: longest file first, a
file's tests together and in order, untimed files after the timed ones, browser tests last."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import pytest

from tests.conftest import file_of, run_order


@dataclass
class Item:
    """What ``run_order`` reads of a ``pytest.Item``: its node id and its browser marker."""

    nodeid: str
    browser: bool = False

    def get_closest_marker(self, name: str) -> Any:
        return object() if name == "browser" and self.browser else None


def order(items: list[Item], seconds: dict[str, float]) -> list[str]:
    ran = run_order(cast(list[pytest.Item], items), seconds)
    return [item.nodeid for item in cast(list[Item], ran)]


def test_longest_file_first_tests_kept_together_untimed_after_browser_last() -> None:
    items = [
        Item("tests/a/test_quick.py::test_1"),
        Item("tests/a/test_quick.py::test_2"),
        Item("tests/browser/test_page.py::test_page", browser=True),
        Item("tests/b/test_untimed.py::test_1"),
        Item("tests/c/test_long.py::test_1[x]"),
        Item("tests/c/test_long.py::test_1[y]"),
        Item("tests/d/test_new.py::test_1"),
    ]
    seconds = {"tests/a/test_quick.py": 1.5, "tests/c/test_long.py": 80.0, "tests/gone.py": 9.0}
    assert order(items, seconds) == [
        "tests/c/test_long.py::test_1[x]",
        "tests/c/test_long.py::test_1[y]",
        "tests/a/test_quick.py::test_1",
        "tests/a/test_quick.py::test_2",
        "tests/b/test_untimed.py::test_1",
        "tests/d/test_new.py::test_1",
        "tests/browser/test_page.py::test_page",
    ]


def test_without_timings_the_collection_order_stays_but_browser_tests_go_last() -> None:
    items = [Item("tests/browser/test_page.py::t", browser=True), Item("tests/z.py::t")]
    assert order(items, {}) == ["tests/z.py::t", "tests/browser/test_page.py::t"]


def test_a_node_ids_file() -> None:
    assert file_of("tests/x/test_y.py::Test::test_z[1-a::b]") == "tests/x/test_y.py"
