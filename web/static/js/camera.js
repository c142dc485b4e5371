// Camera panel: live JPEG frames from sensor_msgs/CompressedImage (tracking overlay drawn by the
// server), with frames per second and camera-to-screen latency. When the picture stops the last
// frame stays, greyed, and says how old it is (freshness.js calls showAge).

import { ageText } from "./freshness.js";
import { setText, stampSeconds } from "./util.js";

const PAUSED_MS = 1000; // no frame for this long: paused (fps() says 0 from then on too)

export class CameraPanel {
  /**
   * @param {{img: HTMLImageElement, empty: HTMLElement, fps: HTMLElement, latency: HTMLElement}} els
   * @param {() => number} serverNow current server time in seconds (clock offset applied)
   */
  constructor(els, serverNow) {
    this.els = els;
    this.serverNow = serverNow;
    this.frameTimes = [];
    this.latencies = [];
    this.frames = 0;
    this.lastUrl = null;
    this.decoding = false;
    this.pending = null;
    this.staleAge = null; // seconds, while the picture is stale (freshness.js)
    /** Called on every frame shown: a word from the camera. */
    this.onFrame = () => {};
    this.timer = setInterval(() => this.render(), 500);
  }

  /** Handle one CompressedImage message. */
  onImage(msg) {
    if (!msg || typeof msg.data !== "string" || msg.data.length === 0) return;
    const fmt = String(msg.format || "jpeg").toLowerCase();
    const mime = fmt.includes("png") ? "image/png" : "image/jpeg";
    // Keep only the newest frame while one is decoding: the screen shows the present, not a backlog.
    this.pending = { data: msg.data, mime, stamp: stampSeconds(msg.header?.stamp) };
    if (!this.decoding) this.showNext();
  }

  showNext() {
    const frame = this.pending;
    this.pending = null;
    if (!frame) return;
    this.decoding = true;
    const img = this.els.img;
    const done = () => {
      this.decoding = false;
      const now = performance.now();
      this.frames += 1;
      this.frameTimes.push(now);
      if (frame.stamp !== null) {
        this.latencies.push((this.serverNow() - frame.stamp) * 1000);
        if (this.latencies.length > 30) this.latencies.shift();
      }
      this.els.empty.hidden = true;
      this.onFrame();
      if (this.pending) this.showNext();
    };
    img.onload = done;
    img.onerror = done; // a corrupt frame is skipped; the next one replaces it
    img.src = `data:${frame.mime};base64,${frame.data}`;
  }

  /** Frames per second over the last two seconds (0 when the stream stalled for a second). */
  fps() {
    const now = performance.now();
    const t = this.frameTimes;
    while (t.length && now - t[0] > 2000) t.shift();
    if (t.length < 2 || now - t[t.length - 1] > 1000) return 0;
    // Intervals between the frames seen, not a count over the window: right from the start.
    return ((t.length - 1) * 1000) / Math.max(1, t[t.length - 1] - t[0]);
  }

  latencyMs() {
    if (!this.latencies.length) return null;
    const sorted = [...this.latencies].sort((a, b) => a - b);
    return sorted[Math.floor(sorted.length / 2)];
  }

  /** The picture's age while it is stale (null: fresh), from the page's one rule. */
  showAge(ageS) {
    this.staleAge = ageS;
    this.render();
  }

  render() {
    const fps = this.fps();
    const stale = this.staleAge !== null;
    setText(this.els.fps, `${fps.toFixed(fps < 10 ? 1 : 0)} fps`);
    const lat = stale ? null : this.latencyMs();
    setText(this.els.latency, lat === null ? "– ms" : `${Math.max(0, Math.round(lat))} ms`);
    this.els.img.dataset.frames = String(this.frames);
    if (this.frames === 0) {
      setText(this.els.empty, "No video yet");
      this.els.empty.hidden = false;
    } else if (stale) {
      setText(this.els.empty, `Picture ${ageText(this.staleAge)}`);
      this.els.empty.hidden = false;
    } else if (performance.now() - (this.frameTimes.at(-1) ?? 0) > PAUSED_MS) {
      // A replay paused (the page's rule is off then): the picture is the recording's.
      setText(this.els.empty, "Video paused");
      this.els.empty.hidden = false;
    } else {
      this.els.empty.hidden = true;
    }
  }

  reset() {
    this.frameTimes = [];
    this.latencies = [];
  }
}
