// Alerts an operator cannot miss: a banner that stays until acknowledged, a warning tone made
// with Web Audio (no sound file to load), and speech where the browser has voices. Low battery,
// link lost, geofence, estimator trouble and every other ANS alarm (Reply level "alert") come
// here, as does a link loss the page sees itself.
//
// Voices: Chromium without speech-dispatcher has none (speechSynthesis.getVoices() is empty), so
// "Voice on" would be a lie. checkVoices() tells the page which case it is in; the console then
// offers replies spoken by the server (espeak-ng, GET /api/v1/tts) where the server has it.

// A two-tone alarm, 880 Hz then 660 Hz (the ISO 7731 style falling pair), 0.18 s each, repeated
// every REPEAT_MS until acknowledged.
export const TONE_HZ = [880, 660];
export const TONE_S = 0.18;
export const REPEAT_MS = 5000;

export class AlertBanner {
  /**
   * @param {{banner: HTMLElement, text: HTMLElement, ack: HTMLButtonElement}} els
   * @param {{AudioContext?: typeof AudioContext, onAck?: (text: string) => void}} env
   */
  constructor(els, env = {}) {
    this.els = els;
    this.Audio = env.AudioContext ?? window.AudioContext ?? window.webkitAudioContext ?? null;
    this.onAck = env.onAck ?? (() => {});
    this.ctx = null;
    this.active = [];
    this.tones = 0;
    this.timer = null;
    els.ack.addEventListener("click", () => this.acknowledge());
  }

  /** Raise (or refresh) an alert keyed by ``key`` (e.g. "link", "battery", "ans:geofence");
   *  ``at``: when it was raised (a replay's alarms carry the recording's time). */
  raise(key, text, at = new Date()) {
    const known = this.active.find((a) => a.key === key);
    if (known && known.over) {
      // It came back before anyone acknowledged that it was over: a new episode.
      Object.assign(known, { text, at, over: false });
      this.tone();
    } else if (known) {
      known.text = text;
    } else {
      this.active.push({ key, text, at });
      this.tone();
    }
    this.render();
    if (!this.timer) this.timer = setInterval(() => this.tone(), REPEAT_MS);
  }

  /** New words for an alarm still standing (an age that grows); nothing once acknowledged. */
  update(key, text) {
    const a = this.active.find((x) => x.key === key);
    if (a && !a.over && a.text !== text) {
      a.text = text;
      this.render();
    }
  }

  /** The condition is over (link back): the banner says so until acknowledged. */
  clear(key, text) {
    const a = this.active.find((x) => x.key === key);
    if (a && text) {
      a.text = text;
      a.over = true;
      this.render();
    }
  }

  /** Forget an alert another one now covers (no acknowledgement needed). */
  drop(key) {
    this.active = this.active.filter((a) => a.key !== key);
    if (!this.active.length) {
      clearInterval(this.timer);
      this.timer = null;
    }
    this.render();
  }

  acknowledge() {
    const texts = this.active.map((a) => a.text);
    this.active = [];
    clearInterval(this.timer);
    this.timer = null;
    this.render();
    this.onAck(texts.join(" "));
  }

  /** One line per alarm, newest last; a line too long for the screen ends in "…" (its
   *  whole text in its title, and in the dialog where the server said it). */
  render() {
    const b = this.els.banner;
    if (!this.active.length) {
      b.hidden = true;
      this.els.text.replaceChildren();
      delete b.dataset.keys;
      return;
    }
    const stamp = (d) => d.toLocaleTimeString([], { hour12: false });
    const lines = this.active.map((a) => {
      const line = document.createElement("li");
      line.className = "alert-line";
      line.dataset.key = a.key;
      if (a.over) line.dataset.over = "true";
      line.title = `${a.text} (${stamp(a.at)})`;
      const text = document.createElement("span");
      text.className = "alert-line-text";
      text.textContent = a.text;
      const at = document.createElement("time");
      at.className = "alert-line-at";
      at.textContent = ` (${stamp(a.at)})`;
      line.append(text, at);
      return line;
    });
    this.els.text.replaceChildren(...lines);
    b.dataset.keys = this.active.map((a) => a.key).join(" ");
    b.hidden = false;
  }

  /** Play the warning tone; counts plays in ``tones`` (the tests read it). */
  tone() {
    if (!this.active.some((a) => !a.over)) return;
    this.tones += 1;
    if (!this.Audio) return;
    try {
      this.ctx = this.ctx || new this.Audio();
      // Autoplay policy: a context made before any user gesture starts suspended.
      if (this.ctx.state === "suspended") this.ctx.resume().catch(() => {});
      const t0 = this.ctx.currentTime + 0.01;
      TONE_HZ.forEach((hz, i) => {
        const osc = this.ctx.createOscillator();
        const gain = this.ctx.createGain();
        osc.type = "square";
        osc.frequency.value = hz;
        gain.gain.setValueAtTime(0.15, t0 + i * TONE_S);
        gain.gain.setValueAtTime(0, t0 + (i + 1) * TONE_S);
        osc.connect(gain).connect(this.ctx.destination);
        osc.start(t0 + i * TONE_S);
        osc.stop(t0 + (i + 1) * TONE_S);
      });
    } catch {
      /* no audio device: the banner still stands */
    }
  }
}

/**
 * Whether the browser can speak: resolves to the number of voices (0 = none), waiting up to
 * ``waitMs`` for "voiceschanged" (Chrome loads voices asynchronously).
 */
export function checkVoices(synth, waitMs = 1500) {
  if (!synth || typeof synth.getVoices !== "function") return Promise.resolve(0);
  const now = synth.getVoices().length;
  if (now) return Promise.resolve(now);
  return new Promise((resolve) => {
    const done = () => resolve(synth.getVoices().length);
    const timer = setTimeout(done, waitMs);
    try {
      synth.addEventListener?.("voiceschanged", () => {
        clearTimeout(timer);
        done();
      });
    } catch {
      /* old engines: the timeout answers */
    }
  });
}
