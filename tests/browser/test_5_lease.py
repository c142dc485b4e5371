"""A page's own commands while it claims the pilot lease: the server holds the lease for the
page's session from the moment it takes the claim, so a take-off clicked before the claim's
answer reaches the page must wait for it and speak for the lease, not be refused as another
pilot's. The claim's answer is held back 2 s here (a slow link, a busy page) to open that window.
"""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import ServerProcess, open_console

pytestmark = pytest.mark.browser

# Hold back the rosbridge answer that gives this page the lease (/console/lease, held_by_me) by
# 2 s; window.__leaseHeld counts the answers held.
HOLD_LEASE_ANSWER = """(() => {
  const desc = Object.getOwnPropertyDescriptor(WebSocket.prototype, "onmessage");
  Object.defineProperty(WebSocket.prototype, "onmessage", {
    configurable: true,
    get() { return desc.get.call(this); },
    set(fn) {
      desc.set.call(this, (ev) => {
        let m = null;
        try { m = JSON.parse(ev.data); } catch (e) { /* binary or not JSON: pass it on */ }
        if (m && m.op === "service_response" && m.service === "/console/lease"
            && m.values && m.values.held_by_me) {
          window.__leaseHeld = (window.__leaseHeld || 0) + 1;
          setTimeout(() => fn(ev), 2000);
          return;
        }
        fn(ev);
      });
    },
  });
})();"""


def test_a_take_off_clicked_while_the_page_claims_the_lease_speaks_for_it(
    browser: Any, own_server: ServerProcess
) -> None:
    ctx, cp = open_console(browser, own_server.url(), init_script=HOLD_LEASE_ANSWER)
    page = cp.page
    try:
        page.wait_for_function("() => window.__leaseHeld >= 1", timeout=20_000)
        assert page.evaluate("uavConsole.haveLease") is None  # the answer is still held
        page.wait_for_selector("#btn-takeoff:not([disabled])", timeout=5_000)
        with page.expect_response(lambda r: r.url.endswith("/drones/uav1/takeoff")) as info:
            page.click("#btn-takeoff")
        response = info.value
        assert response.request.headers.get("x-pilot-lease"), "sent without the page's lease"
        assert response.status == 200, response.text()
        assert "another pilot" not in (page.text_content("#banner") or "")
        assert page.evaluate("uavConsole.haveLease") is True
        page.click("#btn-land")
        assert cp.console_errors() == []
    finally:
        ctx.close()
