"""The console's EMERGENCY button stops the drone while the web process is stopped (SIGSTOP):
the click reaches the simulator's wire through the vehicle's safety port (issue 14's target
"browser click → AT*REF emergency bit"). Debian's Chromium through Playwright; the simulator
runs in the test process. ``UAVC_SKIP_BROWSER=1`` skips it where Chromium is missing."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from drone.sim.probe import SimThread
from tests.browser.conftest import CHROMIUM, CHROMIUM_ARGS, open_console
from tests.isolation.conftest import HOST, PILOT, serve, wait_for

pytestmark = [
    pytest.mark.timeout(180),
    pytest.mark.skipif(os.environ.get("UAVC_SKIP_BROWSER") == "1", reason="UAVC_SKIP_BROWSER=1"),
]


def test_emergency_button_reaches_the_wire_while_the_web_process_is_stopped(
    tmp_path: Path,
) -> None:
    from playwright.sync_api import sync_playwright

    addr = "127.0.13.13"
    with (
        SimThread(addr) as sim,
        serve(tmp_path, addr, extra=("--vehicles", "process")) as srv,
        sync_playwright() as pw,
    ):
        srv.wait_vehicle()
        browser = pw.chromium.launch(
            executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS
        )
        try:
            assert srv.command("take off")["accepted"]  # before the page takes the lease
            wait_for(lambda: sim.truth.flying and sim.truth.z > 0.5, "take-off", 30)
            ctx, cp = open_console(browser, f"http://{HOST}:{srv.port}/?token={PILOT}")
            # the page learns the safety port from its status poll
            page = cp.page
            page.wait_for_function(
                "() => [...performance.getEntriesByType('resource')]"
                ".filter(e => e.name.includes('/api/v1/drones/uav1')).length >= 2",
                timeout=20_000,
            )
            srv.pause()
            try:
                t0 = time.monotonic()
                page.click("#btn-emergency")
                wait_for(lambda: sim.sim.first_emergency_after(t0), "AT*REF emergency", 15)
                wait_for(lambda: sim.truth.emergency, "the drone's emergency state", 10)
                assert srv.proc.poll() is None  # the web process is stopped, not gone
            finally:
                srv.resume()
            ctx.close()
        finally:
            browser.close()
