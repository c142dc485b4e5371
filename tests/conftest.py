"""Suite-wide settings: Hypothesis is derandomized, and the browser tests run last.

Hypothesis draws from a fixed seed per test (``derandomize``), so a run that passes passes
again; a failure it finds is kept as an ``@example`` in the test. Its per-example deadline is
off: it is a timing assertion, and on a loaded machine it fails tests that are right (speed is
measured in ``bench/``).

Playwright's sync API keeps its own event loop running in the main thread for as long as its
session-scoped fixture lives, so no asyncio test (pytest-asyncio) can run after the first
browser test; running the browser tests last keeps both kinds in one ``pytest`` run.

In a pytest-xdist worker (``make test``'s first run, ``--dist loadfile --no-loadscope-reorder``)
the test files are collected longest first, by the seconds each took in the last run that
recorded them (pytest's cache, ``uav-console/file-seconds``): xdist hands files out in
collection order, and a long file handed out last keeps one worker busy while the other idles.
Files not yet timed keep their place after the timed ones. A plain ``pytest`` run keeps the
collection order.
"""

from __future__ import annotations

import pytest
from hypothesis import settings

settings.register_profile("uav-console", derandomize=True, print_blob=True, deadline=None)
settings.load_profile("uav-console")


FILE_SECONDS = "uav-console/file-seconds"  # pytest cache key: test file -> seconds last run
_ran: dict[str, float] = {}  # this run's seconds per test file (setup, call and teardown)


def file_of(nodeid: str) -> str:
    """The test file of a node id (``tests/x/test_y.py::test_z[1]`` -> ``tests/x/test_y.py``)."""
    return nodeid.split("::", 1)[0]


def run_order(items: list[pytest.Item], seconds: dict[str, float]) -> list[pytest.Item]:
    """Browser tests last; before them, the files that took longest first (a file's tests stay
    together and in their order; untimed files after the timed ones, in collection order)."""
    return sorted(
        items,
        key=lambda item: (
            item.get_closest_marker("browser") is not None,
            -seconds.get(file_of(item.nodeid), 0.0),
        ),
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    cache = getattr(config, "cache", None)
    in_worker = hasattr(config, "workerinput")  # pytest-xdist's worker processes
    seconds = cache.get(FILE_SECONDS, {}) if cache is not None and in_worker else {}
    items[:] = run_order(items, seconds)


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _ran[file_of(report.nodeid)] = _ran.get(file_of(report.nodeid), 0.0) + report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    """The seconds of each file that ran, kept for the next run's order (by the xdist
    controller, which hears every worker's reports, or by a plain run; never by a worker)."""
    cache = getattr(session.config, "cache", None)
    if cache is None or hasattr(session.config, "workerinput") or not _ran:
        return
    cache.set(FILE_SECONDS, {**cache.get(FILE_SECONDS, {}), **_ran})
