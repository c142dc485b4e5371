"""The training panel: a pilot with the lease injects simulator faults from the page.

Link loss raises the link alarm on the page; a wind gust blows the hovering drone off its spot
(ground truth from GET /api/v1/sim/uav1/truth). Observers never see the panel.
"""

from __future__ import annotations

import math
from typing import Any

import pytest

from tests.browser.conftest import ServerProcess, open_console
from tests.browser.helpers import is_flying, position, wait_until

pytestmark = pytest.mark.browser


def test_training_panel_link_loss_and_wind_gust(browser: Any, own_server: ServerProcess) -> None:
    server = own_server
    ctx, cp = open_console(browser, server.url())
    octx, observer = open_console(browser, server.url("observer-token-for-browser-tests"))
    page = cp.page
    try:
        # A pilot with the lease on a simulated drone: the panel is there; an observer's is not.
        page.wait_for_selector("#training:not([hidden])", timeout=15_000)
        observer.page.wait_for_selector("#role[data-role='observer']", timeout=10_000)
        observer.page.wait_for_timeout(1500)  # a few status polls: it stays hidden
        assert observer.page.is_hidden("#training")

        page.click("#btn-takeoff")
        ok, truth, _ = wait_until(server.truth, lambda t: is_flying(t) and position(t)[2] > 0.6, 30)
        assert ok, truth
        page.click("#training > summary")

        # Link loss: the page raises the link alarm (ANS link monitor, or the page's own).
        page.fill("#training input[data-fault='link_loss']", "3")
        page.click("#training button[data-fault='link_loss']")
        page.wait_for_function(
            "(document.querySelector('#alert-banner').dataset.keys || '').includes('uav1:link')",
            timeout=15_000,
        )
        assert "link" in page.inner_text("#alert-text").lower()
        status = page.inner_text("#training .training-status")
        assert "link loss for 3 s on uav1" in status
        # the link comes back on its own; the drone hovered meanwhile (its watchdog)
        ok, truth, _ = wait_until(
            lambda: server.api("GET", "/drones/uav1").json(), lambda d: d["link_ok"], 20
        )
        assert ok, truth
        page.click("#alert-ack")

        # A gust from the west blows the hovering drone east, then it holds again.
        x0, y0, _ = position(server.truth())
        page.select_option("#training select[data-fault='wind-from']", "west")
        page.fill("#training input[data-fault='wind']", "6")
        page.click("#training button[data-fault='wind']")
        ok, truth, _ = wait_until(server.truth, lambda t: position(t)[0] - x0 > 0.15, 10)
        assert ok, (x0, y0, truth)
        x1, y1, _ = position(truth)
        assert x1 - x0 > abs(y1 - y0)  # blown east, not north or south
        assert math.isfinite(x1)

        page.click("#training button[data-fault='clear']")
        page.wait_for_function(
            "document.querySelector('#training .training-status').textContent"
            ".includes('all faults cleared')"
        )
        page.click("#btn-land")
        ok, truth, _ = wait_until(server.truth, lambda t: not is_flying(t), 30)
        assert ok, truth
        assert cp.console_errors() == [] and observer.console_errors() == []
    finally:
        ctx.close()
        octx.close()
