"""Age on every value (web/static/js/freshness.js), in Chromium, by stopping each source for real.

A real ``serve --vehicles process`` flies a simulated AR.Drone that this test process runs
(``drone.sim.probe.SimThread``), whose camera can be stopped while its navdata flows on. Each
source is stopped in turn and the page must grey the panels it feeds, say "n s old" and raise
an alarm that names the source (and only that one), then say when it is back:

- the camera: its encoder waits, as a hung camera would;
- the vehicle process: SIGSTOP (frozen) with the drone hovering, then SIGKILL (serve restarts it);
- the web server: SIGSTOP (the page's socket stays open, nothing comes), also with a fleet,
  whose list greys out with it.

``UAVC_SKIP_BROWSER=1`` skips it where Chromium is missing.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drone.sim.probe import ProbeSim, SimThread
from tests.browser.conftest import ServerProcess, open_console
from tests.isolation.conftest import HOST, PILOT, Served, serve, wait_for
from tests.support.loopback import fresh_address

pytestmark = [
    pytest.mark.browser,
    pytest.mark.timeout(400),
    pytest.mark.skipif(os.environ.get("UAVC_SKIP_BROWSER") == "1", reason="UAVC_SKIP_BROWSER=1"),
]
SIM_ADDR = fresh_address()

# What the page shows of its sources' ages, in one read.
VIEW = """() => {
  const q = (s) => document.querySelector(s);
  const stale = (s) => q(s)?.dataset.stale === 'true';
  const shown = (el) => (el && !el.hidden ? el.textContent : '');
  const badge = (s) => shown(q(s + ' .age-badge'));
  const grey = (s) => getComputedStyle(q(s)).filter.includes('grayscale');
  return {
    sources: document.body.dataset.stale ?? null,
    telemetry: stale('#telemetry-panel'), telemetryAge: badge('#telemetry-panel'),
    map: stale('#map-panel'), mapAge: badge('#map-panel'),
    camera: stale('#camera-panel'), cameraSays: shown(q('#camera-empty')),
    statusbar: stale('#statusbar'), statusSays: shown(q('#sb-stale')),
    chips: ['#sb-flight', '#sb-battery', '#sb-task'].map(stale),
    rec: stale('#rec'),
    greyTiles: ['#m-state', '#m-altitude', '#m-battery', '#m-loop'].map(grey),
    linkTile: [grey('#m-link'), q('#m-link').dataset.level],
    alarms: [...document.querySelectorAll('#alert-text .alert-line')].map((l) => [
      l.dataset.key, l.querySelector('.alert-line-text').textContent, l.dataset.over === 'true',
    ]),
    pill: q('#conn').textContent,
  };
}"""


class CameraSim(ProbeSim):
    """The simulator with a camera that can stop: while ``camera_on`` is clear its encoder waits
    (as a hung camera does) and no frame leaves; navdata and commands carry on."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.camera_on = threading.Event()
        self.camera_on.set()

    def _frame_bytes(self, encoder: Any, truth: Any) -> bytes:
        self.camera_on.wait()
        return super()._frame_bytes(encoder, truth)


@pytest.fixture(scope="module")
def rig(
    tmp_path_factory: pytest.TempPathFactory, browser: Any
) -> Iterator[tuple[SimThread, Served, Any]]:
    tmp: Path = tmp_path_factory.mktemp("freshness")
    sim = SimThread(SIM_ADDR)
    camera = CameraSim(SIM_ADDR, "indoor", seed=1)
    sim.sim = camera
    try:
        with sim, serve(tmp, SIM_ADDR, extra=("--vehicles", "process")) as srv:
            srv.wait_vehicle()
            yield sim, srv, browser
    finally:
        camera.camera_on.set()  # a waiting encoder thread must end


def view(page: Any) -> dict[str, Any]:
    return dict(page.evaluate(VIEW))


def until(page: Any, pred: Any, what: str, timeout: float = 30.0) -> dict[str, Any]:
    """Poll the page's view until ``pred(view)``; returns that view."""
    return dict(wait_for(lambda: v if pred(v := view(page)) else None, what, timeout))


def open_page(browser: Any, srv: Served) -> tuple[Any, Any]:
    """The console (its own CSP; evaluate runs over CDP), connected, live video and navdata."""
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, service_workers="block")
    page = ctx.new_page()
    page.goto(f"http://{HOST}:{srv.port}/?token={PILOT}")
    wait_for(
        lambda: page.evaluate(
            """document.querySelector('#conn').dataset.state === 'open'
               && Number(document.querySelector('#camera').dataset.frames || 0) > 3
               && document.querySelector('#link').textContent.endsWith('Hz')"""
        ),
        "the page live (video and navdata)",
        40,
    )
    until(page, lambda v: v["sources"] == "", "every source fresh")
    return ctx, page


def alarm(v: dict[str, Any], key: str) -> tuple[str, bool] | None:
    """(text, over) of the alarm line ``key`` on the page, or None."""
    return next(((text, over) for k, text, over in v["alarms"] if k == key), None)


def test_a_stopped_camera_greys_the_picture_and_says_so(
    rig: tuple[SimThread, Served, Any],
) -> None:
    sim, srv, browser = rig
    camera: CameraSim = sim.sim  # type: ignore[assignment]
    ctx, page = open_page(browser, srv)
    try:
        camera.camera_on.clear()
        try:
            v = until(page, lambda v: v["camera"] and alarm(v, "fresh:camera:uav1"), "camera stale")
            assert v["cameraSays"].startswith("Picture ") and v["cameraSays"].endswith(" s old")
            text, over = alarm(v, "fresh:camera:uav1")  # type: ignore[misc]
            assert text.startswith("uav1: no picture from the camera for") and not over
            # only the camera: its navdata flows, so telemetry and map are live
            assert not v["telemetry"] and not v["map"] and not v["statusbar"]
            assert v["sources"] == "camera"
        finally:
            camera.camera_on.set()
        v = until(page, lambda v: not v["camera"] and not v["cameraSays"], "the camera back")
        text, over = alarm(v, "fresh:camera:uav1")  # type: ignore[misc]
        assert over and text.startswith("uav1: the camera is back (it was silent for")
        assert v["cameraSays"] == ""
    finally:
        ctx.close()


def test_a_frozen_vehicle_process_greys_every_value_it_feeds(
    rig: tuple[SimThread, Served, Any],
) -> None:
    sim, srv, browser = rig
    ctx, page = open_page(browser, srv)
    wait_for(lambda: page.evaluate("uavConsole.haveLease === true"), "the page's lease", 20)
    page.click("#btn-takeoff")  # the page holds the lease: its pilot flies
    wait_for(lambda: sim.truth.flying and sim.truth.z > 0.6, "take-off", 30)
    wait_for(lambda: page.text_content("#ctrl-state") == "Hovering", "Hovering on the page", 20)
    pid = int(srv.vehicle()["pid"])
    os.kill(pid, signal.SIGSTOP)
    try:
        v = until(
            page,
            lambda v: (
                v["telemetry"]
                and "(its vehicle process does not answer)"
                in ((alarm(v, "fresh:vehicle:uav1") or ("", False))[0])
            ),
            "telemetry stale, the vehicle named",
        )
        # state "Hovering", altitude, battery and the control loop: greyed, with their age
        assert v["greyTiles"] == [True, True, True, True], v
        assert v["telemetryAge"].endswith(" s old") and v["mapAge"].endswith(" s old")
        assert v["map"] and v["chips"] == [True, True, True]
        assert page.text_content("#ctrl-state") == "Hovering"  # the last word, shown as old
        # the Link tile is what says it: red, not greyed
        assert v["linkTile"] == [False, "alert"]
        # the server is fine: its bar is live, and no alarm blames it
        assert not v["statusbar"] and alarm(v, "fresh:server") is None
        assert v["pill"] == "Connected"
    finally:
        os.kill(pid, signal.SIGCONT)
    v = until(page, lambda v: not v["telemetry"] and not v["map"], "telemetry fresh again")
    text, over = alarm(v, "fresh:vehicle:uav1")  # type: ignore[misc]
    assert over and text.startswith("uav1: telemetry is back (it was silent for")
    assert v["greyTiles"] == [False, False, False, False]
    page.click("#btn-land")
    wait_for(lambda: not sim.truth.flying, "landing", 30)
    ctx.close()


def test_a_killed_vehicle_process_raises_its_alarm_until_a_new_one_speaks(
    rig: tuple[SimThread, Served, Any],
) -> None:
    _sim, srv, browser = rig
    ctx, page = open_page(browser, srv)
    try:
        old = int(srv.vehicle()["pid"])
        os.kill(old, signal.SIGKILL)
        seen: list[dict[str, Any]] = []  # every view read, to tell what the page went through

        def raised(v: dict[str, Any]) -> bool:
            seen.append(v)
            return alarm(v, "fresh:vehicle:uav1") is not None

        until(page, raised, "the vehicle's alarm after the kill")
        first = alarm(seen[-1], "fresh:vehicle:uav1")
        # raised while it is silent, its panels greyed in the same view; or, where the new
        # process spoke before the alarm was due or before this test's next read (a busy
        # machine), raised as the page learns of the new process and said back at once
        assert first[0].startswith(  # type: ignore[index]
            ("uav1: no telemetry for", "uav1: telemetry is back (it was silent for")
        ), first
        if first[0].startswith("uav1: no telemetry for"):  # type: ignore[index]
            assert seen[-1]["telemetry"] and seen[-1]["map"], seen[-1]
        # one alarm, its cause: the camera behind the vehicle is greyed, not blamed
        assert all(alarm(v, "fresh:camera:uav1") is None for v in seen)
        wait_for(lambda: (x := srv.wait_vehicle(timeout=60))["pid"] != old and x, "a new one", 60)
        # every source fresh, and the alarm said back (on the tick after the page learns of the
        # new process, when the restart came after the rule's own "back" line)
        v = until(
            page,
            lambda v: v["sources"] == "" and (alarm(v, "fresh:vehicle:uav1") or ("", False))[1],
            "every source fresh again and the alarm said back",
            60,
        )
        assert alarm(v, "fresh:vehicle:uav1")[0].startswith("uav1: ")  # type: ignore[index]
        # the new process's camera opening after its telemetry is the restart, not the camera
        assert alarm(v, "fresh:camera:uav1") is None, v["alarms"]
    finally:
        ctx.close()


# The rule on an injected clock: a vehicle and its camera; the vehicle silent 3 s and back
# (or replaced), the camera 4 s later still; then a camera that never comes back.
RESTART = """async () => {
  const { Freshness, START_GRACE_S } = await import('/static/js/freshness.js');
  const run = (how) => {
    let t = 0;
    const shown = new Map();
    const alarms = { raise: (k, x) => shown.set(k, x), update: (k, x) => shown.set(k, x),
                     clear: (k, x) => shown.set(k, 'back: ' + x), drop: (k) => shown.delete(k) };
    const f = new Freshness({ now: () => t, alarms });
    f.source('vehicle', { alarm: (a) => 'no telemetry for ' + a, back: (a) => 'telemetry ' + a });
    f.source('camera', { upstream: 'vehicle', alarm: (a) => 'no picture for ' + a,
                         back: (a) => 'picture ' + a });
    const step = (until, beats) => { while (t < until - 1e-9) {
      t = Math.round((t + 0.25) * 100) / 100; beats.forEach((b) => f.beat(b)); f.tick(); } };
    step(2, ['vehicle', 'camera']);
    step(how === 'rule' ? 5 : 2.5, []);          // the process dies
    if (how === 'replaced') f.replaced('vehicle', 'restarted');
    step(9, ['vehicle']);                          // the new one: telemetry, no picture yet
    const early = Object.fromEntries(shown);
    const greyed = f.staleAge('camera') !== null;
    step(9 + START_GRACE_S, ['vehicle']);          // and its camera never comes
    return { early, greyed, late: Object.fromEntries(shown) };
  };
  return { rule: run('rule'), replaced: run('replaced') };
}"""


def test_a_camera_behind_a_restarted_vehicle_gets_time_to_open(
    rig: tuple[SimThread, Served, Any],
) -> None:
    """Seen by the rule (the vehicle silent, then back) or told (a new pid before the rule
    saw it): the camera, silent 4 s after its vehicle is back, is greyed but not blamed; a
    camera still silent once the start grace is over raises its own alarm."""
    _sim, srv, browser = rig
    ctx = browser.new_context(service_workers="block")
    page = ctx.new_page()
    try:
        page.goto(f"http://{HOST}:{srv.port}/?token={PILOT}")
        out = page.evaluate(RESTART)
        rule, replaced = out["rule"], out["replaced"]
        assert rule["early"] == {"fresh:vehicle": "back: telemetry 3.3 s"}, rule
        for run in (rule, replaced):
            assert list(run["early"]) == ["fresh:vehicle"] and run["greyed"], run
            assert run["late"]["fresh:camera"].startswith("no picture for "), run
    finally:
        ctx.close()


def test_a_vehicle_process_restarted_while_the_page_was_frozen_is_still_said(
    rig: tuple[SimThread, Served, Any],
) -> None:
    """The page frozen (a phone's background tab) while the vehicle process is killed and
    restarted: it never sees the silence, but the new process (another pid) raises the alarm,
    naming the restart, and it stays, said back, until acknowledged."""
    _sim, srv, browser = rig
    ctx, page = open_page(browser, srv)
    cdp = ctx.new_cdp_session(page)
    try:
        old = int(srv.vehicle()["pid"])
        cdp.send("Page.setWebLifecycleState", {"state": "frozen"})
        try:
            os.kill(old, signal.SIGKILL)
            wait_for(lambda: (x := srv.wait_vehicle(timeout=60))["pid"] != old and x, "new", 60)
        finally:
            cdp.send("Page.setWebLifecycleState", {"state": "active"})
        v = until(page, lambda v: alarm(v, "fresh:vehicle:uav1"), "the vehicle's alarm")
        restarted = "; its vehicle process was restarted)."
        v = until(
            page,
            lambda v: (
                v["sources"] == ""
                and alarm(v, "fresh:vehicle:uav1")[1]
                and alarm(v, "fresh:vehicle:uav1")[0].endswith(restarted)
            ),
            "said back, naming the restart",
        )
        text, over = alarm(v, "fresh:vehicle:uav1")  # type: ignore[misc]
        assert over and text.startswith("uav1: telemetry is back (it was silent for"), text
        # the page's own freeze blames no source, and the camera behind the vehicle is not named
        assert alarm(v, "fresh:server") is None and alarm(v, "fresh:camera:uav1") is None
    finally:
        ctx.close()


def test_a_frozen_server_greys_the_whole_page_and_names_the_server(
    rig: tuple[SimThread, Served, Any],
) -> None:
    _sim, srv, browser = rig
    ctx, page = open_page(browser, srv)
    try:
        srv.pause()
        try:
            v = until(
                page,
                lambda v: v["statusbar"] and v["telemetry"] and v["camera"] and v["map"],
                "every panel stale",
            )
            assert v["pill"] == "Server not answering"
            assert v["rec"] or page.is_hidden("#rec")  # ● REC is greyed when it shows
            assert " s old · no word from the server since " in v["statusSays"]
            assert v["telemetryAge"].endswith(" s old") and v["cameraSays"].endswith(" s old")
            text, over = alarm(v, "fresh:server")  # type: ignore[misc]
            assert text.startswith("No word from the server for") and not over
            # the sources behind the server are stale with it, but only the server is blamed
            assert alarm(v, "fresh:vehicle:uav1") is None and alarm(v, "fresh:camera:uav1") is None
        finally:
            srv.resume()
        v = until(page, lambda v: v["sources"] == "", "every source fresh again", 60)
        text, over = alarm(v, "fresh:server")  # type: ignore[misc]
        assert over and text.startswith("The server answers again")
        assert v["pill"] == "Connected" and v["statusSays"] == ""
    finally:
        ctx.close()


def test_a_fleet_list_greys_out_with_a_frozen_server(
    browser: Any, fleet_server: ServerProcess
) -> None:
    """Two drones (inline): the fleet list and every panel grey out while the server is frozen;
    the fleet status behind it is greyed, not blamed."""
    ctx, cp = open_console(browser, fleet_server.url())
    page = cp.page
    proc = fleet_server.proc
    assert proc is not None
    try:
        page.wait_for_selector("#fleet-list li", timeout=15_000)
        until(page, lambda v: v["sources"] == "", "every source fresh")
        assert page.get_attribute("#fleet-list", "data-stale") == "false"
        os.kill(proc.pid, signal.SIGSTOP)
        try:
            v = until(page, lambda v: "fleet" in (v["sources"] or "").split(), "fleet stale")
            assert page.get_attribute("#fleet-list", "data-stale") == "true"
            assert v["map"] and v["telemetry"] and v["statusbar"]
            assert page.eval_on_selector(
                "#fleet-list", "l => getComputedStyle(l).filter.includes('grayscale')"
            )
            v = until(page, lambda v: alarm(v, "fresh:server") is not None, "the server named")
            assert alarm(v, "fresh:fleet") is None
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        until(page, lambda v: v["sources"] == "", "every source fresh again", 60)
        assert page.get_attribute("#fleet-list", "data-stale") == "false"
    finally:
        ctx.close()
