"""The console page says when each command was issued: a page whose clock runs 5 s behind the
server's (and that learnt no offset: on loopback it assumes none) issues every command 5 s in
the past, so its take-off button and its typed "take off" are not flown, and the page shows why.
A page on time flies (tests/browser/test_2_flight.py)."""

from __future__ import annotations

import time
from typing import Any

import pytest

from tests.browser.conftest import ServerProcess, open_console
from tests.browser.helpers import is_flying

pytestmark = pytest.mark.browser

# The page's clock 5 s behind: Date.now() is what it stamps commands with.
BEHIND = "(() => { const now = Date.now; Date.now = () => now.call(Date) - 5000; })();"


def test_a_page_whose_commands_are_late_does_not_fly(
    browser: Any, own_server: ServerProcess
) -> None:
    ctx, cp = open_console(browser, own_server.url(), init_script=BEHIND)
    page = cp.page
    try:
        page.wait_for_selector("#btn-takeoff:not([disabled])", timeout=20_000)
        sent: list[dict[str, str]] = []
        page.on(
            "request",
            lambda r: sent.append(r.headers) if r.url.endswith("/drones/uav1/takeoff") else None,
        )
        page.click("#btn-takeoff")
        page.wait_for_function(
            "() => document.querySelector('#banner').textContent.includes('Not flown')",
            timeout=10_000,
        )
        banner = page.text_content("#banner") or ""
        assert "Not flown: 'take off' reached the drone 5." in banner, banner
        issued = float(sent[0]["x-command-issued"])
        assert 4.0 < time.time() - issued < 30.0
        page.fill("#text-input", "take off")
        page.press("#text-input", "Enter")
        page.wait_for_function(
            "() => [...document.querySelectorAll('#dialog .msg-bot .text')]"
            ".filter(e => e.textContent.startsWith(\"Not flown: 'take off'\")).length >= 2",
            timeout=10_000,
        )
        assert not is_flying(own_server.truth())
        assert cp.console_errors() == []
    finally:
        ctx.close()
