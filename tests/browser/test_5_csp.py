"""The console under its own Content-Security-Policy (issue 14): Chromium loads the page
without bypassing the CSP, connects, learns its role and shows the camera, and reports no
CSP violation; the token cookie is set, so a reload without ``?token=`` still connects."""

from __future__ import annotations

import time
from typing import Any

from .conftest import ServerProcess


def poll(page: Any, js: str, timeout_s: float = 20.0) -> Any:
    """``page.evaluate(js)`` until truthy (evaluate runs over CDP, outside the page's CSP)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = page.evaluate(js)
        if value or time.monotonic() > deadline:
            return value
        page.wait_for_timeout(100)


def test_console_works_under_its_csp(browser: Any, server: ServerProcess) -> None:
    ctx = browser.new_context(viewport={"width": 1440, "height": 900}, service_workers="block")
    try:
        page = ctx.new_page()
        violations: list[str] = []
        page.on(
            "console", lambda m: violations.append(m.text) if "Content Security" in m.text else None
        )
        page.add_init_script(
            "document.addEventListener('securitypolicyviolation', e =>"
            " console.error('Content Security Policy violation: ' + e.violatedDirective"
            " + ' ' + e.blockedURI))"
        )
        response = page.goto(server.url())
        assert response is not None
        csp = response.headers["content-security-policy"]
        assert "script-src 'self'" in csp and "frame-ancestors 'none'" in csp
        assert poll(page, "document.querySelector('#conn').dataset.state === 'open'")
        assert poll(page, "document.querySelector('#role').dataset.role === 'pilot'")
        assert poll(page, "Number(document.querySelector('#camera').dataset.frames || 0) > 0")
        assert violations == []
        # the first load set the HttpOnly cookie: the page's script cannot read it ...
        assert "uavc_token" not in page.evaluate("document.cookie")
        cookies = {c["name"]: c for c in ctx.cookies()}
        assert cookies["uavc_token"]["httpOnly"] and cookies["uavc_token"]["sameSite"] == "Strict"
        # ... and REST accepts it without the token in the address
        status = page.evaluate("fetch('/api/v1/drones').then(r => r.status)")
        assert status == 200
    finally:
        ctx.close()
