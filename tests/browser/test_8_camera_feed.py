"""The camera subscription steps its throttle up when frames queue and down when they are on
time again (web/static/js/camera_feed.js), in Chromium, on a clock the test drives; and the
console's own feed is throttled by the server (rosbridge ``throttle_rate``) when asked."""

from __future__ import annotations

from typing import Any

from tests.browser.conftest import ConsolePage

DRIVE = """async () => {
  const { CameraFeed, STEPS_MS } = await import('/static/js/camera_feed.js');
  const subs = [];
  const ros = { subscribe(topic, type, cb, opts) {
    const s = { topic, opts, cb, live: true, unsubscribe() { s.live = false; } };
    subs.push(s); return s; } };
  const shown = [];
  let t = 0, server = 1780000000;
  const feed = new CameraFeed(ros, { onImage: (m) => shown.push(m) }, () => server, () => t);
  feed.attach('/uav1/ardrone/image_raw/compressed', 'sensor_msgs/CompressedImage');
  const frame = (lateMs) => { const s = server - lateMs / 1000;
    subs.filter(x => x.live).forEach(x => x.cb({ header: { stamp: { sec: Math.floor(s),
      nanosec: Math.round((s % 1) * 1e9) } }, data: 'x' })); };
  const levels = [];
  // 3 s of frames arriving 40 ms late, then a backlog growing 300 ms a second, then on time
  for (let i = 0; i < 45; i++) { t += 66; server += 0.066; frame(40); }
  levels.push(feed.throttleMs);
  for (let i = 0; i < 60; i++) { t += 66; server += 0.066; frame(450 + i * 20); }
  levels.push(feed.throttleMs);
  for (let i = 0; i < 200; i++) { t += 66; server += 0.066; frame(30); }
  levels.push(feed.throttleMs);
  return { levels, steps: STEPS_MS, shown: shown.length,
           subscribed: subs.map(s => s.opts.throttle_rate), live: subs.filter(s => s.live).length };
}"""


def test_the_throttle_follows_the_backlog(console: ConsolePage) -> None:
    out: dict[str, Any] = console.page.evaluate(DRIVE)
    assert out["levels"][0] == 0  # on time: every frame
    assert out["levels"][1] >= 200  # queueing: fewer frames until the backlog is gone
    assert out["levels"][2] == 0  # on time again: back to every frame
    assert out["shown"] == 45 + 60 + 200  # every frame that came was shown
    assert out["subscribed"][0] == 0 and max(out["subscribed"]) == out["levels"][1]
    assert out["live"] == 1  # one subscription at a time


def test_the_console_subscribes_its_camera_through_the_feed(console: ConsolePage) -> None:
    page = console.page
    page.wait_for_function("uavConsole.cameraFeed.sub !== null", timeout=10_000)
    assert page.evaluate("uavConsole.cameraFeed.topic") == "/ardrone/image_raw/compressed"
    page.wait_for_function(
        "Number(document.querySelector('#camera').dataset.frames || 0) > 2", timeout=15_000
    )
    assert console.console_errors() == []
