"""A fleet: the drone selector picks which drone's topics the panels show and the jog drives;
a bare answer goes to the drone that asked."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import ServerProcess, open_console
from tests.browser.helpers import SPEECH_STANDIN, is_flying, position, wait_until

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


def test_a_typed_yes_answers_the_drone_that_asked(
    browser: Any, fleet_server: ServerProcess
) -> None:
    """uav2 is selected; "uav1, take off" heard at 0.4 is read back by uav1; a typed "yes"
    (no drone named) goes to uav1, which asked, and uav1 takes off; uav2 stays down."""
    ctx, cp = open_console(browser, fleet_server.url(), init_script=SPEECH_STANDIN)
    try:
        page = cp.page
        page.wait_for_selector("#drone-select-wrap:not([hidden])", timeout=10_000)
        page.select_option("#drone-select", "uav2")
        page.wait_for_function("uavConsole.haveLease === true", timeout=5000)
        n = page.locator("#dialog .msg-bot").count()
        page.evaluate("window.__speech.next = {text: 'uav1, take off', confidence: 0.4}")
        page.click("#mic")
        asked = page.locator("#dialog .msg-bot").nth(n)
        asked.wait_for(timeout=8000)
        # the line says which drone once: in its tag, not again in its text
        assert asked.locator(".who").text_content() == "uav1"
        assert asked.locator(".text").text_content().startswith('Did you say "take off"?')
        assert asked.locator(".answers").get_attribute("data-drone") == "uav1"
        page.fill("#text-input", "yes")
        page.press("#text-input", "Enter")
        ok, truth, took = wait_until(
            lambda: fleet_server.truth("uav1"), lambda t: position(t)[2] > 0.5, timeout_s=20
        )
        assert ok, f"uav1 did not take off on the yes ({took:.0f} s): {truth}"
        assert not is_flying(fleet_server.truth("uav2"))
        assert asked.locator(".answers button").first.is_disabled()  # answered
        page.fill("#text-input", "uav1, land")
        page.press("#text-input", "Enter")
        ok, truth, _ = wait_until(
            lambda: fleet_server.truth("uav1"), lambda t: not is_flying(t), timeout_s=20
        )
        assert ok, truth
    finally:
        ctx.close()
