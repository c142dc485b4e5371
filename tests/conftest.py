"""Suite-wide settings: Hypothesis is derandomized, and the browser tests run last.

Hypothesis draws from a fixed seed per test (``derandomize``), so a run that passes passes
again; a failure it finds is kept as an ``@example`` in the test. Its per-example deadline is
off: it is a timing assertion, and on a loaded machine it fails tests that are right (speed is
measured in ``bench/``).

Playwright's sync API keeps its own event loop running in the main thread for as long as its
session-scoped fixture lives, so no asyncio test (pytest-asyncio) can run after the first
browser test; running the browser tests last keeps both kinds in one ``pytest`` run.
"""

from __future__ import annotations

import pytest
from hypothesis import settings

settings.register_profile("uav-console", derandomize=True, print_blob=True, deadline=None)
settings.load_profile("uav-console")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("browser") is not None)
