"""The Central patrol from the console (issue 13 item 9): the button starts a persistent patrol
of both drones, the panel shows live coverage (time since each waypoint was last visited, the
longest gap, each drone's role and battery), a typed "stop the patrol" stops it, and a typed
"start the patrol with all drones" and the stop button do the same."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.browser.conftest import OBSERVER, ServerProcess, _server, open_console
from tests.support.loopback import fresh_address
from tests.support.polling import until

pytestmark = pytest.mark.browser


@pytest.fixture
def central_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """Two simulated drones of this test's own."""
    yield from _server(tmp_path_factory, "uavc-browser-central", fresh_address(2), "--fleet", "2")


def _type(page: Any, text: str) -> None:
    page.fill("#text-input", text)
    page.press("#text-input", "Enter")


def test_central_button_and_voice(browser: Any, central_server: ServerProcess) -> None:
    ctx, cp = open_console(browser, central_server.url())
    try:
        page = cp.page
        page.wait_for_function(  # both drones have joined the fleet and are ready
            "document.querySelectorAll('#central-drones li[data-role=\"idle\"]').length === 2",
            timeout=60_000,
        )
        assert page.text_content("#central-state") == "not running"
        assert page.get_attribute("#central", "open") is None  # folded: the map keeps its room
        page.click("#central-h")
        assert page.is_enabled("#central-start") and not page.is_enabled("#central-stop")

        page.click("#central-start")
        page.wait_for_function(  # the reply, whatever it is (a loaded machine answers late)
            "!document.querySelector('#central-reply').textContent.endsWith('…')",
            timeout=30_000,
        )
        reply = str(page.text_content("#central-reply"))
        assert reply.startswith("Starting the patrol of 12 waypoints with 2 drones"), reply
        page.wait_for_selector("#central[data-running='true']", timeout=5000)
        assert not page.is_enabled("#central-start") and page.is_enabled("#central-stop")
        # live coverage: a drone patrols, waypoints are visited and their age counts up
        page.wait_for_selector("#central-drones li[data-role='patrolling']", timeout=20_000)
        page.wait_for_selector("#central-waypoints li[data-visited='true']", timeout=45_000)
        assert page.eval_on_selector_all("#central-waypoints li", "ls => ls.length") == 12
        first = page.text_content("#central-waypoints li[data-visited='true']")
        assert first is not None and first.endswith(" s ago"), first
        gap = page.text_content("#central-gap")
        assert gap is not None and gap.endswith(" s"), gap
        # route coverage, its longest gap and the handoffs, as GET /patrol has them
        page.wait_for_function(
            "document.querySelector('#central-coverage').textContent.endsWith(' %')",
            timeout=20_000,
        )
        route = central_server.api("GET", "/patrol").json()["mission"]["coverage"]["route"]
        shown = float(str(page.text_content("#central-coverage")).removesuffix(" %"))
        assert 0.0 <= shown <= 100.0 and abs(shown - route["coverage_pct"]) <= 5.0, (shown, route)
        assert str(page.text_content("#central-cov-gap")).endswith(" s")
        assert page.text_content("#central-handoffs") == "0"
        drones = page.eval_on_selector_all("#central-drones li", "ls => ls.map(l => l.textContent)")
        assert any("patrolling, battery" in d and d.endswith("%") for d in drones), drones
        assert len(drones) == 2, drones

        _type(page, "stop the patrol")
        page.wait_for_function(
            # dialog entries are div.msg in a role=log div (issue 18), no longer list items
            "[...document.querySelectorAll('#dialog .msg-bot')].some(m => "
            "m.textContent.includes('Stopping the patrol; the drones are flying home.'))",
            timeout=10_000,
        )
        page.wait_for_selector("#central[data-running='false']", timeout=5000)
        page.wait_for_selector("#central-drones li[data-role='returning']", timeout=5000)
        assert central_server.api("GET", "/patrol").json()["running"] is False

        _type(page, "start the patrol with all drones")
        page.wait_for_selector("#central[data-running='true']", timeout=10_000)
        page.click("#central-stop")
        page.wait_for_function(
            "document.querySelector('#central-reply').textContent"
            ".startsWith('Stopping the patrol')",
            timeout=5000,
        )
        page.wait_for_selector("#central[data-running='false']", timeout=5000)
    finally:
        ctx.close()

    # an observer sees the panel but cannot start the patrol
    ctx, cp = open_console(browser, central_server.url(OBSERVER))
    try:
        page = cp.page
        page.wait_for_function("document.body.dataset.role === 'observer'", timeout=10_000)
        page.wait_for_function(
            "document.querySelectorAll('#central-drones li').length === 2", timeout=10_000
        )
        page.wait_for_function("document.querySelector('#central-start').disabled", timeout=5000)
    finally:
        ctx.close()


@pytest.fixture
def paused_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """Two simulated drones of this test's own."""
    yield from _server(tmp_path_factory, "uavc-browser-paused", fresh_address(2), "--fleet", "2")


def test_land_pauses_the_patrol_and_the_panel_resumes_and_ends_it(
    browser: Any, paused_server: ServerProcess
) -> None:
    """Issue 26 finding 7: the page's Land on the patrolling drone pauses the mission; the
    panel says so with the drone's role and offers Resume and End, which work."""
    ctx, cp = open_console(browser, paused_server.url())
    try:
        page = cp.page
        page.wait_for_function(
            "document.querySelectorAll('#central-drones li[data-role=\"idle\"]').length === 2",
            timeout=60_000,
        )
        page.click("#central-h")
        page.click("#central-start")
        page.wait_for_selector("#central[data-state='running']", timeout=30_000)
        status = paused_server.api("GET", "/patrol").json()
        active = status["mission"]["active"]
        # the page's own Land button, on the patrolling drone
        page.wait_for_selector("#drone-select-wrap:not([hidden])", timeout=10_000)
        page.select_option("#drone-select", active)
        page.wait_for_function(f"window.uavConsole.drone === '{active}'", timeout=5000)
        page.click("#btn-land")
        page.wait_for_selector("#central[data-state='paused']", timeout=10_000)
        line = page.text_content("#central-state") or ""
        assert "paused by the operator (land)" in line and f"{active} was patrolling" in line
        assert page.is_visible("#central-resume") and page.is_enabled("#central-resume")
        assert not page.is_visible("#central-start")
        assert page.is_enabled("#central-stop")
        assert page.text_content(f"#central-drones li[data-drone='{active}']").startswith(
            f"{active}: paused"
        )

        page.click("#central-resume")
        page.wait_for_function(
            "document.querySelector('#central-reply').textContent"
            ".startsWith('Resuming the patrol')",
            timeout=5000,
        )
        page.wait_for_selector("#central[data-state='running']", timeout=45_000)
        assert not page.is_visible("#central-resume") and page.is_visible("#central-start")
        # the mission has a drone on its way again (it is "running" before the central has
        # sent one, and an End then rightly says its drones are on the ground)
        until(
            lambda: paused_server.api("GET", "/patrol").json()["mission"].get("active"),
            45,
            "a drone sent again after Resume",
        )

        page.click("#central-stop")
        page.wait_for_selector("#central[data-state='none']", timeout=5000)
        reply = page.text_content("#central-reply")
        assert reply == "Stopping the patrol; the drones are flying home.", reply
        assert page.text_content("#central-state") == "not running"
        assert not cp.errors, cp.errors
    finally:
        ctx.close()
