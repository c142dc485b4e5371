"""The console's recordings menu and REC pill on the live server (after the flights before)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.browser.conftest import ConsolePage, ServerProcess

pytestmark = pytest.mark.browser


def test_recordings_menu_lists_and_downloads_flights(
    console: ConsolePage, server: ServerProcess
) -> None:
    page: Any = console.page
    flights = server.api("GET", "/flights").json()["flights"]
    page.wait_for_selector("#recordings:not([hidden])", timeout=10_000)
    page.click("#recordings > summary")
    if not flights:  # this file run alone: nothing flew yet
        page.wait_for_function(
            "document.querySelector('#recordings-list').textContent.includes('No recordings')"
        )
        assert page.is_hidden("#rec")
        return
    page.wait_for_function(
        f"document.querySelectorAll('#recordings-list li').length >= {len(flights)}",
        timeout=10_000,
    )
    recording = any(f["ended"] is None for f in flights)
    if recording:
        page.wait_for_selector("#rec:not([hidden])", timeout=10_000)
    links = page.eval_on_selector_all("#recordings-list a", "els => els.map(a => a.href)")
    assert len(links) >= len([f for f in flights if f["ended"] is not None]) - 1
    if links:
        # No credential in the link (history, logs): the browser's cookie fetches the file ...
        assert all("token" not in href for href in links), links
        with page.expect_download(timeout=30_000) as download:
            page.click("#recordings-list a")
        assert Path(download.value.path()).read_bytes()[:8] == b"\x89MCAP0\r\n"
        # ... which the link alone, without it, cannot.
        assert httpx.get(links[0], timeout=30).status_code == 401
    assert console.console_errors() == []
