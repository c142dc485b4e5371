"""Stops from the page (issue 26): any pilot may Land and Hover, lease or not (finding 6); the
two-road stop logic of web/static/js/stops.js driven with stand-in roads in the page's own
module system; the status bar's road health on a server whose drone runs inline (no door)."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import ConsolePage, ServerProcess, open_console

pytestmark = pytest.mark.browser


def test_a_pilot_without_the_lease_can_land_and_hover(browser: Any, server: ServerProcess) -> None:
    ctx_a, first = open_console(browser, server.url())
    ctx_b = None
    try:
        first.page.wait_for_function("uavConsole.haveLease === true", timeout=10_000)
        ctx_b, second = open_console(browser, server.url())
        b = second.page
        b.wait_for_selector("#takeover:not([hidden])", timeout=10_000)
        # only what needs the lease is off; the stops stay (the server lets any pilot stop)
        assert b.is_disabled("#btn-takeoff") and b.is_disabled("[data-jog='left']")
        assert b.is_enabled("#btn-land") and b.is_enabled("#btn-hover")
        assert b.is_enabled("#btn-emergency")
        b.click("#btn-land")
        b.wait_for_function("document.body.dataset.stop === 'delivered'", timeout=10_000)
        said = b.evaluate("document.body.dataset.stopText")
        assert said.startswith("Land: land delivered at") and "by the server" in said, said
        b.evaluate("document.body.dataset.stop = ''; document.activeElement.blur()")
        b.keyboard.press("Space")  # the keyboard's hover, lease or not
        b.wait_for_function("document.body.dataset.stop === 'delivered'", timeout=10_000)
        assert b.evaluate("document.body.dataset.stopText").startswith("Hover: hover delivered")
        # no door on an inline drone: the bar says so; the server road is healthy
        assert b.text_content("#sb-door-v") == "none" and b.text_content("#sb-server-v") == "ok"
    finally:
        ctx_a.close()
        if ctx_b is not None:
            ctx_b.close()


STOP_UNITS = """async () => {
  const s = await import('/static/js/stops.js');
  const out = {};
  // stand-in roads: a door that records what it is sent, a REST call the test settles
  const door = () => {
    const d = { sent: [], send(m) { d.sent.push(m); return true; } };
    return d;
  };
  const rest = () => {
    const r = { calls: [], aborted: 0 };
    r.fn = (stop, body, signal) => new Promise((resolve, reject) => {
      r.calls.push({ body, resolve, reject });
      signal.addEventListener('abort', () => { r.aborted += 1; });
    });
    return r;
  };
  const make = (d, r, extra = {}) => new s.StopSender({
    rest: r.fn, door: () => d, serverNow: () => 1000, newId: () => 'id-' + Math.random(),
    retryMs: 5, ...extra,
  });

  // 1. the door acknowledges first: delivered by the door; the REST request is aborted
  let d = door(), r = rest(), sender = make(d, r);
  let stop = sender.send('uav1', 'emergency');
  out.firstPending = stop.text(0).text;
  out.doorFrame = d.sent[0];
  out.restBody = r.calls[0].body;
  sender.doorAck({ op: 'ack', id: stop.id, action: 'emergency', accepted: true,
                   detail: 'emergency delivered', delivered: 1005.4, road: 'door', late_s: 5.4 });
  out.doorWins = [stop.state, stop.text(0).text.replace(/at [0-9:]+/, 'at T'), r.aborted];

  // 2. REST answers "sent, not confirmed": it asks again with the same id until confirmed
  d = null; r = rest(); sender = make(d, r);
  stop = sender.send('uav1', 'land');
  out.oneRoad = stop.text(0).text;
  r.calls[0].resolve({ accepted: true, detail: 'land sent; not confirmed', delivered: null });
  await new Promise((ok) => setTimeout(ok, 50));
  out.retriedSameId = r.calls.length >= 2 && r.calls[1].body.id === stop.id;
  r.calls.at(-1).resolve({ accepted: true, detail: 'land delivered', delivered: 1000.2,
                           road: 'server', late_s: 0.2 });
  await new Promise((ok) => setTimeout(ok, 10));
  out.restWins = [stop.state, stop.ack.road];

  // 3. a REST error that will not change (403) with a door that never answers: still pending
  d = door(); r = rest(); sender = make(d, r);
  stop = sender.send('uav1', 'hover');
  const err = new Error('observer may not command'); err.status = 403;
  r.calls[0].reject(err);
  await new Promise((ok) => setTimeout(ok, 20));
  out.doorStillTrying = [stop.state, stop.text(0).text];
  // 4. a newer command supersedes it: the door is told, nothing is pending
  const dropped = sender.supersede();
  out.superseded = [dropped.length, stop.state, d.sent.at(-1), stop.text(0).text];
  out.nothingLeft = sender.supersede().length;

  // 5. no door and the server refuses: not sent, said so (never "pending" for ever)
  r = rest(); sender = make(null, r);
  stop = sender.send('uav1', 'land');
  r.calls[0].reject(err);
  await new Promise((ok) => setTimeout(ok, 20));
  out.unsent = [stop.state, stop.text(0).text];

  // 6. a door that opens later gets the pending stops
  d = door(); r = rest(); let opened = null;
  sender = make(null, r, { door: () => opened });
  stop = sender.send('uav2', 'emergency');
  opened = d;
  sender.doorOpened('uav2');
  out.sentOnOpen = d.sent.map((m) => m.op + ':' + m.id === 'stop:' + stop.id);
  out.ids = /^[A-Za-z0-9_.:-]{1,64}$/.test(s.newStopId());

  // 7. superseded while both roads were stalled, but the server road brought it first: the
  // door answers "too_late" and the page says it ran (never "dropped" for a stop that ran)
  d = door(); r = rest(); sender = make(d, r);
  stop = sender.send('uav1', 'emergency');
  sender.supersede();
  sender.doorSuperseded({ op: 'superseded', ids: [], too_late: [stop.id] });
  out.ranAnyway = [stop.state, stop.text(0).text];
  // 8. a supersede the door did not answer (it was down) goes again when it reopens; one
  // dropped there is forgotten, and a resent stop's ack that it ran is said
  d = door(); r = rest(); sender = make(d, r);
  const kept = sender.send('uav1', 'land');
  const ran = sender.send('uav1', 'hover');
  sender.supersede();
  d.sent = [];
  sender.doorOpened('uav1');
  out.supersedeAgain = d.sent.map((m) => [m.op, [...m.ids].sort()]);
  out.droppedIds = [kept.id, ran.id].sort();
  sender.doorSuperseded({ op: 'superseded', ids: [kept.id], too_late: [] });
  sender.doorAck({ op: 'ack', id: ran.id, action: 'hover', accepted: true,
                   detail: 'hover delivered', delivered: 1002, road: 'server', late_s: 2.0 });
  out.afterAnswers = [kept.state, ran.state, ran.text(0).text.replace(/at [0-9:]+/, 'at T')];
  d.sent = [];
  sender.doorOpened('uav1');
  out.nothingAgain = d.sent.length;
  return out;
}"""


def test_stop_logic_units(console: ConsolePage) -> None:
    out = console.page.evaluate(STOP_UNITS)
    assert out["firstPending"] == "Emergency stop: stop pending, retrying on 2 roads"
    assert out["doorFrame"]["op"] == "stop" and out["doorFrame"]["issued"] == 1000
    assert out["restBody"]["id"] == out["doorFrame"]["id"]
    state, text, aborted = out["doorWins"]
    assert state == "delivered" and aborted == 1
    assert text == "Emergency stop: stopped at T (delivered after 5.4 s, by the safety door)"
    assert out["oneRoad"] == "Land: stop pending, retrying on 1 road"
    assert out["retriedSameId"] and out["restWins"] == ["delivered", "server"]
    assert out["doorStillTrying"] == ["pending", "Hover: stop pending, retrying on 1 road"]
    count, state, frame, text = out["superseded"]
    assert count == 1 and state == "superseded" and frame["op"] == "supersede"
    assert text == "Hover: the pending stop was dropped (a newer command superseded it)"
    assert out["nothingLeft"] == 0
    assert out["unsent"] == ["unsent", "Land could not be sent: observer may not command"]
    assert out["sentOnOpen"] == [True] and out["ids"]
    assert out["ranAnyway"] == [
        "ran",
        "Emergency stop: not dropped, it had already reached the drone",
    ]
    assert out["supersedeAgain"] == [["supersede", out["droppedIds"]]]
    assert out["afterAnswers"] == [
        "superseded",
        "ran",
        "Hover: not dropped, it had already reached the drone at T 2.0 s after it was issued,"
        " by the server",
    ]
    assert out["nothingAgain"] == 0
