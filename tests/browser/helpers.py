"""Helpers shared by the browser tests: stand-ins for the Web Speech API and truth polling."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

# A stand-in SpeechRecognition (the browser's own needs Google's servers). Tests put the next
# result in window.__speech.next = {text, confidence}; start() then delivers one interim and one
# final result, as Chrome does, and ends. speechSynthesis is replaced by a recorder so the test
# can check what was spoken without an audio device.
SPEECH_STANDIN = """
(() => {
  const state = { next: null, started: 0, spoken: [] };
  window.__speech = state;
  const result = (text, confidence, isFinal) => {
    const alt = { transcript: text, confidence };
    const r = [alt];
    r.isFinal = isFinal;
    r.item = (i) => r[i];
    return r;
  };
  class StandInRecognition {
    constructor() { this.lang = ""; this.continuous = false; this.interimResults = false; }
    start() {
      state.started += 1;
      const next = state.next;
      state.next = null;
      setTimeout(() => {
        if (!next) {
          this.onerror && this.onerror({ error: "no-speech" });
          this.onend && this.onend();
          return;
        }
        const words = next.text.split(" ");
        const head = words.slice(0, Math.max(1, words.length - 1)).join(" ");
        const interim = [result(head, 0.5, false)];
        this.onresult && this.onresult({ resultIndex: 0, results: interim });
        setTimeout(() => {
          state.interimSeen = document.getElementById("interim").textContent;
          const final = [result(next.text, next.confidence, true)];
          this.onresult && this.onresult({ resultIndex: 0, results: final });
          this.onend && this.onend();
        }, 60);
      }, 30);
    }
    stop() { this.onend && this.onend(); }
    abort() { this.onend && this.onend(); }
  }
  window.SpeechRecognition = StandInRecognition;
  window.webkitSpeechRecognition = StandInRecognition;
  // A browser recogniser that works on this device: the Recogniser setting's "auto" uses it.
  try { localStorage.setItem("uavc.browserSpeech", "works"); } catch (e) { /* opaque origin */ }
  const synth = {
    speaking: false, pending: false, paused: false,
    speak(u) { state.spoken.push(u.text); },
    cancel() {}, pause() {}, resume() {},
    getVoices() { return [{ name: "stand-in", lang: "en-US" }]; },
    addEventListener() {}, removeEventListener() {},
  };
  Object.defineProperty(window, "speechSynthesis", { value: synth, configurable: true });
})();
"""

NO_SPEECH = """
(() => {
  delete window.SpeechRecognition;
  delete window.webkitSpeechRecognition;
  for (const name of ["SpeechRecognition", "webkitSpeechRecognition"]) {
    Object.defineProperty(window, name, { value: undefined, configurable: true });
  }
})();
"""


def type_command(page: Any, text: str) -> None:
    """Type a command into the console's text box and send it."""
    page.fill("#text-input", text)
    page.press("#text-input", "Enter")


def position(truth: dict[str, Any]) -> tuple[float, float, float]:
    """(x, y, z) in metres from a /sim/{id}/truth body (flat or nested under ``position``)."""
    src = truth.get("position", truth)
    return float(src["x"]), float(src["y"]), float(src["z"])


def speed(truth: dict[str, Any]) -> float:
    src = truth.get("velocity", truth)
    return math.sqrt(sum(float(src.get(k, 0.0)) ** 2 for k in ("vx", "vy", "vz")))


def is_flying(truth: dict[str, Any]) -> bool:
    return bool(truth.get("flying", position(truth)[2] > 0.1))


def motors_cut(truth: dict[str, Any]) -> bool:
    """The simulator's emergency state (motors off) or the drone no longer flying."""
    return bool(truth.get("emergency")) or not is_flying(truth)


def wait_until(
    probe: Callable[[], Any], ok: Callable[[Any], bool], timeout_s: float, period_s: float = 0.1
) -> tuple[bool, Any, float]:
    """Poll ``probe`` until ``ok(value)``; returns (reached, last value, seconds taken)."""
    start = time.monotonic()
    value = probe()
    while not ok(value):
        if time.monotonic() - start > timeout_s:
            return False, value, time.monotonic() - start
        time.sleep(period_s)
        value = probe()
    return True, value, time.monotonic() - start


def refused_jog(page: Any, reason: str, speed: float, timeout_ms: int) -> None:
    """Publish a jog (``/cmd_vel`` at ``speed`` m/s forward) from the page and wait for the
    server's error status whose message matches the regular expression ``reason``."""
    page.evaluate("""() => { window.__statuses = [];
        uavConsole.ros.addEventListener('status', e => window.__statuses.push(e.detail)); }""")
    page.evaluate(
        """(x) => uavConsole.ros.publish('/cmd_vel', 'geometry_msgs/Twist',
        {linear: {x, y: 0, z: 0}, angular: {x: 0, y: 0, z: 0}})""",
        speed,
    )
    page.wait_for_function(
        "(r) => window.__statuses.some(s => s.level === 'error' && new RegExp(r, 'i').test(s.msg))",
        arg=reason,
        timeout=timeout_ms,
    )
