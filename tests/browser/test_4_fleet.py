"""A fleet: the drone selector picks which drone's topics the panels show and the jog drives."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import ServerProcess, open_console

pytestmark = pytest.mark.browser


def test_drone_selector_switches_topics(browser: Any, fleet_server: ServerProcess) -> None:
    ctx, cp = open_console(browser, fleet_server.url())
    try:
        page = cp.page
        page.wait_for_selector("#drone-select-wrap:not([hidden])", timeout=10_000)
        options = page.eval_on_selector_all("#drone-select option", "os => os.map(o => o.value)")
        assert options == ["uav1", "uav2"]
        page.select_option("#drone-select", "uav2")
        assert page.get_attribute("body", "data-drone") == "uav2"
        # The panels now follow /uav2/...: navdata keeps arriving for the chosen drone.
        page.wait_for_function(
            "document.querySelector('#link').textContent.endsWith('Hz')", timeout=15_000
        )
        subscribed = page.evaluate("[...uavConsole.ros.subscriptions.keys()]")
        assert "/uav2/ardrone/navdata" in subscribed and "/uav1/ardrone/navdata" not in subscribed
        # A held jog key publishes on /uav2/cmd_vel (watched here by a subscription of our own).
        page.wait_for_function("uavConsole.haveLease === true", timeout=5000)
        page.evaluate("""() => { window.__seen = [];
            uavConsole.ros.subscribe('/uav2/cmd_vel', 'geometry_msgs/Twist',
                                     m => window.__seen.push(m)); }""")
        page.click("#arm-keys")  # keys that move the drone need keyboard flying on
        page.wait_for_selector("#arm-keys[aria-pressed='true']", timeout=5000)
        page.click("#camera-panel")
        # Held until two jog messages came back: our own subscription is registered by a
        # round trip to the server, so the first messages of a short hold can precede it.
        page.keyboard.down("q")
        try:
            page.wait_for_function("window.__seen.length >= 2", timeout=10_000)
        finally:
            page.keyboard.up("q")
        seen = page.evaluate("window.__seen")
        assert seen[0]["angular"]["z"] == pytest.approx(0.3)
        page.wait_for_function(
            "window.__seen.length && window.__seen[window.__seen.length - 1].angular.z === 0",
            timeout=3000,
        )
        # The choice survives a reload (kept per browser).
        page.reload()
        page.wait_for_selector("#conn[data-state='open']", timeout=10_000)
        page.wait_for_function("document.body.dataset.drone === 'uav2'", timeout=10_000)
        assert page.input_value("#drone-select") == "uav2"
    finally:
        ctx.close()
