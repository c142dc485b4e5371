"""The page recovers by itself when the server restarts: reconnects, resubscribes, carries on."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import ServerProcess, open_console

pytestmark = pytest.mark.browser


def test_page_recovers_after_server_restart(browser: Any, own_server: ServerProcess) -> None:
    ctx, cp = open_console(browser, own_server.url())
    try:
        page = cp.page
        page.wait_for_function(
            "Number(document.querySelector('#camera').dataset.frames||0) > 2", timeout=20_000
        )
        own_server.stop()
        page.wait_for_selector("#conn:not([data-state='open'])", timeout=10_000)
        # One read of state and text: the page alternates closed/connecting while it retries.
        state, text = page.eval_on_selector("#conn", "el => [el.dataset.state, el.textContent]")
        assert (state, text) in {
            ("closed", "Connection lost — retrying"),
            ("connecting", "Reconnecting…"),
        }
        own_server.start()
        page.wait_for_selector("#conn[data-state='open']", timeout=30_000)
        # Resubscribed: new frames and navdata arrive without a reload.
        before = int(page.eval_on_selector("#camera", "el => Number(el.dataset.frames)"))
        page.wait_for_function(
            "n => Number(document.querySelector('#camera').dataset.frames) > n + 3",
            arg=before,
            timeout=20_000,
        )
        page.wait_for_function(
            "document.querySelector('#link').textContent.endsWith('Hz')", timeout=10_000
        )
        assert "Reconnected." in (page.text_content("#dialog") or "")
        # Publishing works again on the new connection (advertised afresh): a typed command
        # reaches /console/utterance, watched here by a subscription of the page's own.
        page.evaluate("""() => { window.__heard = [];
            uavConsole.ros.subscribe('/console/utterance', 'uav_console/Utterance',
                                     m => window.__heard.push(m)); }""")
        page.wait_for_function("uavConsole.haveLease === true", timeout=5000)
        page.fill("#text-input", "what is your battery")
        page.press("#text-input", "Enter")
        page.wait_for_function(
            "window.__heard.some(m => m.text === 'what is your battery' && m.source === 'text')",
            timeout=5000,
        )
        assert cp.console_errors() == [] or all(
            "ERR_CONNECTION_REFUSED" in e or "WebSocket" in e for e in cp.console_errors()
        ), cp.console_errors()
    finally:
        ctx.close()
