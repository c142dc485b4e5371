"""The page recovers by itself when the server restarts: reconnects, resubscribes, carries on;
while it is away the status bar greys out with "since", and afterwards the page says what was
lost (issue 18: a patrol that no longer runs)."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import ServerProcess, open_console
from tests.browser.helpers import position, type_command, wait_until

pytestmark = pytest.mark.browser


def test_page_recovers_after_server_restart(browser: Any, own_server: ServerProcess) -> None:
    ctx, cp = open_console(browser, own_server.url())
    try:
        page = cp.page
        page.wait_for_function(
            "Number(document.querySelector('#camera').dataset.frames||0) > 2", timeout=20_000
        )
        # Flying a patrol when the server goes away.
        page.wait_for_function("uavConsole.haveLease === true", timeout=10_000)
        page.click("#btn-takeoff")
        ok, truth, _ = wait_until(own_server.truth, lambda t: position(t)[2] > 0.5, timeout_s=20)
        assert ok, truth
        type_command(page, "patrol markers 0 and 1")
        page.wait_for_function(
            "document.getElementById('sb-task-v').textContent.startsWith('patrol')",
            timeout=10_000,
        )
        own_server.stop()
        page.wait_for_selector("#conn:not([data-state='open'])", timeout=10_000)
        page.wait_for_selector("#statusbar[data-stale='true']", timeout=10_000)
        assert "since" in (page.text_content("#sb-stale") or "")
        # One read of state and text: the page alternates closed/connecting while it retries.
        state, text = page.eval_on_selector("#conn", "el => [el.dataset.state, el.textContent]")
        assert (state, text) in {
            ("closed", "Connection lost — retrying"),
            ("connecting", "Reconnecting…"),
        }
        own_server.start()  # a fresh server: the drone is on the ground, no patrol
        page.wait_for_selector("#conn[data-state='open']", timeout=30_000)
        page.wait_for_selector("#statusbar[data-stale='false']", timeout=30_000)
        page.wait_for_function(
            """[...document.querySelectorAll('#dialog .msg-system')]
                .some(e => e.textContent.includes('While disconnected'))""",
            timeout=10_000,
        )
        said = page.evaluate(
            """[...document.querySelectorAll('#dialog .msg-system')]
                .map(e => e.textContent).filter(t => t.includes('While disconnected')).pop()"""
        )
        assert "patrol no longer runs" in said, said
        assert page.is_hidden("#sb-stale")
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
