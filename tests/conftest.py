"""Suite-wide ordering: the browser tests run last.

Playwright's sync API keeps its own event loop running in the main thread for as long as its
session-scoped fixture lives, so no asyncio test (pytest-asyncio) can run after the first
browser test; running the browser tests last keeps both kinds in one ``pytest`` run.
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("browser") is not None)
