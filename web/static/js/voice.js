// Speaking to the drone from any browser: the recogniser setting (server | browser | auto),
// push-to-talk (hold the mic button or the M key) or tap-to-toggle, and a hands-free mode.
//
// `server`: the microphone (getUserMedia + an AudioWorklet, 16 kHz PCM) is streamed over an
// authenticated WebSocket to /api/v1/speech/stream, recognised offline on the console's machine
// (faster-whisper); interim text while speaking; the final text goes down the same dialog path
// as typed text (onFinal -> /console/utterance with source "speech" and its confidence).
// `browser`: the Web Speech API (speech.js). `auto`: the server's, unless the browser's is known
// to work on this device (it has returned text here before; it is a cloud service, so also
// online): Chromium offers the API everywhere and fails where it has no service ("network",
// "audio-capture"). Any error of the browser's recogniser in `auto` switches to the server's
// for good, and the page says so once.

import { SpeechInput, recognitionClass } from "./speech.js";

export const ENGINES = ["auto", "server", "browser"];
const HOLD_MS = 350; // a press held longer than this is push-to-talk; shorter toggles
const STORE_KEY = "uavc.recognizer";
// "works" once the browser's recogniser returned text on this device, "failed" after an error.
export const BROWSER_KEY = "uavc.browserSpeech";
// Errors that say nothing against the engine: the operator stopped it, or said nothing.
const NOT_FAILURES = new Set(["aborted", "no-speech"]);
// After "end" the server answers within its decode time (~1 s here, seconds on a busy
// laptop); past this the operator is told to repeat instead of waiting on silence.
const ANSWER_TIMEOUT_MS = 20000;
// Hands-free: how long after the console stops speaking the microphone still sends silence
// (the reply's reverberation and the loudspeaker's buffered end).
const ECHO_TAIL_MS = 300;
const PAUSED = "Paused while the console speaks: press the microphone (M) to interrupt.";

export function chooseEngine(setting, win = window) {
  if (setting === "server" || setting === "browser") return setting;
  const known = win.localStorage?.getItem(BROWSER_KEY) === "works";
  return known && recognitionClass(win) && win.navigator.onLine !== false ? "browser" : "server";
}

/** The operator's words for a microphone that would not start (never the raw DOM message). */
export function micProblem(err) {
  switch (err?.name) {
    case "NotAllowedError":
    case "SecurityError":
      return "permission was refused";
    case "NotFoundError":
    case "OverconstrainedError":
      return "no microphone was found";
    case "NotReadableError":
      return "the microphone is in use by another program, or the system refused it";
    default:
      return "the browser's audio system failed";
  }
}

export function streamUrl(loc, token, mode, lease) {
  const proto = loc.protocol === "https:" ? "wss:" : "ws:";
  const q = new URLSearchParams({ token: token || "", mode, rate: "16000" });
  if (lease) q.set("lease", lease);
  return `${proto}//${loc.host}/api/v1/speech/stream?${q}`;
}

/** The server recogniser: one microphone capture + one WebSocket per listening period. */
class ServerRecognizer {
  constructor(opts) {
    this.opts = opts; // {token, lease(), onInterim, onFinal, onNotice, onState, speaking()}
    this.ws = null;
    this.ctx = null;
    this.stream = null;
    this.node = null;
    this.active = false;
    this.quietUntil = 0;
    this.mutedChunks = 0; // hands-free audio sent as silence while the console spoke
    this.muted = false; // hands-free: not listening now, the console is speaking
    this.interrupted = false; // the operator talks over the reply now playing (interrupt)
  }

  /**
   * The chunk to send: hands-free, while the console speaks a reply (and ECHO_TAIL_MS after),
   * silence instead of the microphone. Echo cancellation is off (it hurts recognition), so a
   * loudspeaker's "Did you say …?" would otherwise be heard as the operator's next sentence,
   * and every reply would answer the one before it. After ``interrupt`` the microphone is
   * heard again until the reply playing then has ended.
   */
  outgoing(chunk) {
    if (this.mode !== "handsfree") return chunk;
    const now = performance.now();
    const speaking = Boolean(this.opts.speaking?.());
    if (this.interrupted && !speaking) this.interrupted = false; // the next reply mutes again
    if (speaking && !this.interrupted) this.quietUntil = now + ECHO_TAIL_MS;
    this.setMuted(now < this.quietUntil);
    if (!this.muted) return chunk;
    this.mutedChunks += 1;
    return new ArrayBuffer(chunk.byteLength); // zeros: 16-bit PCM silence
  }

  /** The operator pressed the microphone while the console spoke: listen again at once. */
  interrupt() {
    this.interrupted = true;
    this.quietUntil = 0;
    this.setMuted(false);
  }

  setMuted(on) {
    if (on === this.muted) return;
    this.muted = on;
    this.opts.onMuted?.(on);
  }

  async start(mode) {
    const win = window;
    if (!win.isSecureContext || !navigator.mediaDevices?.getUserMedia) {
      this.opts.onNotice(
        "The microphone needs a secure page: open the console's https:// address (see the URL printed by `uav-console serve`).",
      );
      return false;
    }
    this.active = true;
    try {
      this.stream = await navigator.mediaDevices.getUserMedia({
        // Whisper copes with noise itself; the browser's echo cancellation, noise suppression
        // and gain control distort speech (clipping, gating) and cost it accuracy.
        audio: { channelCount: 1, echoCancellation: false, noiseSuppression: false, autoGainControl: false },
      });
      // One AudioContext with the worklet loaded, kept (suspended) between utterances, so a
      // second press is live at once and its first syllable is not lost.
      this.src = await this.connectSource(this.stream);
      if (!this.active) throw new DOMException("stopped before the microphone was live", "AbortError");
      this.node = new AudioWorkletNode(this.ctx, "pcm-downsampler");
      this.src.connect(this.node);
    } catch (err) {
      this.release();
      this.active = false;
      if (err && err.name === "AbortError") return false;
      console.warn("microphone start failed", err);
      this.opts.onNotice(`The microphone could not start (${micProblem(err)}). Type your command instead.`);
      return false;
    }
    this.awaiting = this.endOnOpen = false;
    const ws = new WebSocket(streamUrl(window.location, this.opts.token, mode, this.opts.lease()));
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    const pending = [];
    this.node.port.onmessage = (ev) => {
      const chunk = this.outgoing(ev.data);
      if (ws.readyState === WebSocket.OPEN) ws.send(chunk);
      else if (ws.readyState === WebSocket.CONNECTING) pending.push(chunk);
    };
    ws.onopen = () => {
      for (const buf of pending.splice(0)) ws.send(buf);
      // Released while the socket was still connecting (a slow TLS handshake, a busy
      // server): the captured audio went out above; now ask for its final text.
      if (this.endOnOpen) this.finish(ws);
    };
    ws.onmessage = (ev) => this.onMessage(ev.data);
    ws.onclose = (ev) => {
      clearTimeout(this.answerTimer);
      if (ev.code !== 1000 && ev.code !== 1005 && ev.reason) this.opts.onNotice(`Speech: ${ev.reason}`);
      else if (this.awaiting && this.ws === ws) {
        this.opts.onNotice("The speech connection closed before an answer. Please repeat, or type the command.");
      }
      this.awaiting = this.endOnOpen = false;
      if (this.ws === ws) this.ws = null;
      this.release();
      this.active = false;
      this.opts.onState(false);
    };
    this.opts.onState(true);
    return true;
  }

  /** The microphone as a source in the kept AudioContext; a context that cannot take it (a
   *  closed or broken one, another sample rate) is replaced once. */
  async connectSource(stream) {
    for (let attempt = 0; ; attempt += 1) {
      try {
        if (!this.ctx || this.ctx.state === "closed") {
          this.ctx = new AudioContext();
          await this.ctx.audioWorklet.addModule("/static/js/pcm-worklet.js");
        }
        await this.ctx.resume();
        return this.ctx.createMediaStreamSource(stream);
      } catch (err) {
        if (attempt > 0 || err?.name === "NotAllowedError") throw err;
        this.ctx?.close().catch(() => {});
        this.ctx = null;
      }
    }
  }

  onMessage(data) {
    let msg;
    try {
      msg = JSON.parse(data);
    } catch {
      return;
    }
    if (msg.type === "interim") this.opts.onInterim(msg.text);
    else if (msg.type === "final") {
      clearTimeout(this.answerTimer);
      this.awaiting = false;
      this.opts.onInterim("");
      if (msg.text) this.opts.onFinal(msg.text, Number(msg.confidence) || 0);
      else this.opts.onNotice("I heard no command. Hold the microphone (or M) while you speak.");
      if (this.mode !== "handsfree" && !this.active && this.ws) this.ws.close(1000, "done");
    } else if (msg.type === "error") this.opts.onNotice(`Speech: ${msg.error}`);
  }

  /** Stop capturing; the server decodes what it has and answers with the final text. */
  stop() {
    this.active = false;
    this.release();
    const ws = this.ws;
    if (ws && ws.readyState === WebSocket.OPEN) this.finish(ws);
    else if (ws && ws.readyState === WebSocket.CONNECTING) this.endOnOpen = true;
    else if (ws) ws.close(1000, "stopped");
    this.opts.onState(false);
  }

  /** Ask for the final text of what was sent, and say so if none comes. */
  finish(ws) {
    this.endOnOpen = false;
    this.awaiting = true;
    ws.send(JSON.stringify({ type: "end" }));
    clearTimeout(this.answerTimer);
    this.answerTimer = setTimeout(() => {
      if (this.ws !== ws || !this.awaiting) return;
      this.awaiting = false;
      this.opts.onNotice("Speech recognition did not answer in time. Please repeat, or type the command.");
      ws.close(1000, "no answer");
    }, ANSWER_TIMEOUT_MS);
  }

  release() {
    if (this.node) {
      this.node.port.onmessage = null;
      this.node.disconnect();
    }
    if (this.src) this.src.disconnect();
    if (this.stream) for (const t of this.stream.getTracks()) t.stop();
    if (this.ctx && this.ctx.state === "running") this.ctx.suspend().catch(() => {});
    this.node = this.stream = this.src = null;
  }
}

export class VoiceInput {
  /**
   * @param {{button: HTMLButtonElement, interim: HTMLElement, engine?: HTMLSelectElement,
   *          handsfree?: HTMLInputElement, label?: HTMLElement}} els
   * @param {{token: string, lease: () => (string|null), onFinal: (text: string, c: number) => void,
   *          onNotice: (text: string) => void}} opts
   */
  constructor(els, opts, win = window) {
    this.els = els;
    this.opts = opts;
    this.win = win;
    // The operator's choice on this device, else the server's setting (serve --recognizer).
    const stored = win.localStorage?.getItem(STORE_KEY);
    const served = document.querySelector('meta[name="uavc-recognizer"]')?.content;
    this.setting = ENGINES.includes(stored) ? stored : ENGINES.includes(served) ? served : "auto";
    this.browserFailed = false; // auto: the browser's recogniser failed on this page
    this.toldFallback = false;
    this.deniedWhy = ""; // why this console may not speak commands now (setAllowed)
    this.micWhy = ""; // why the microphone cannot be used here (checkMicrophone)
    this.pressedAt = 0;
    this.listening = false;
    this.allowed = true; // false for observers and pilots without the lease (setAllowed)
    this.browser = new SpeechInput(
      { button: document.createElement("button"), interim: els.interim },
      (text, confidence) => {
        win.localStorage?.setItem(BROWSER_KEY, "works");
        opts.onFinal(text, confidence);
      },
      opts.onNotice,
      win,
      (code) => this.browserError(code),
    );
    const browserState = this.browser.setListening.bind(this.browser);
    this.browser.setListening = (on) => {
      browserState(on);
      if (!on && this.engine === "browser") this.setListening(false, "browser");
    };
    this.server = new ServerRecognizer({
      token: opts.token,
      lease: opts.lease,
      speaking: opts.speaking,
      onInterim: (t) => {
        els.interim.textContent = t ? `“${t}…”` : "";
      },
      onFinal: opts.onFinal,
      onNotice: opts.onNotice,
      onState: (on) => this.setListening(on),
      // Hands-free is deaf while the console speaks: the page says so, and how to interrupt.
      onMuted: (on) => {
        document.body.dataset.speechPaused = on ? "1" : "";
        if (on) els.interim.textContent = PAUSED;
        else if (els.interim.textContent === PAUSED) els.interim.textContent = "";
      },
    });
    const btn = els.button;
    btn.addEventListener("pointerdown", (ev) => {
      if (ev.button === 0) this.press();
    });
    btn.addEventListener("pointerup", () => this.release());
    btn.addEventListener("pointerleave", () => {
      if (this.pressedAt) this.release();
    });
    btn.addEventListener("keydown", (ev) => {
      if ((ev.key === "Enter" || ev.key === " ") && !ev.repeat) {
        ev.preventDefault();
        this.press();
      }
    });
    btn.addEventListener("keyup", (ev) => {
      if (ev.key === "Enter" || ev.key === " ") this.release();
    });
    // The M shortcut (controls.js) calls press(); its release comes here.
    win.addEventListener("keyup", (ev) => {
      if (ev.key && ev.key.toLowerCase() === "m") this.release();
    });
    if (els.engine) {
      els.engine.value = this.setting;
      els.engine.addEventListener("change", () => this.setSetting(els.engine.value));
    }
    if (els.handsfree) els.handsfree.addEventListener("change", () => this.onHandsfree());
    win.addEventListener("online", () => this.showEngine());
    win.addEventListener("offline", () => this.showEngine());
    win.navigator.mediaDevices?.addEventListener?.("devicechange", () => this.checkMicrophone());
    this.showEngine();
    this.checkMicrophone();
  }

  /**
   * An error of the browser's recogniser (speech.js): in `auto`, switch to this console's
   * offline recogniser for good and say so once; true when handled so.
   */
  browserError(code) {
    if (NOT_FAILURES.has(code)) return false;
    this.win.localStorage?.setItem(BROWSER_KEY, "failed");
    if (this.setting !== "auto") return false; // the operator chose it: the error is shown
    this.browserFailed = true;
    this.setListening(false, "browser");
    this.showEngine();
    if (!this.toldFallback) {
      this.toldFallback = true;
      this.opts.onNotice(
        `The browser's speech recognition failed (${code}); this console's offline recogniser listens instead. Press the microphone and speak again.`,
      );
    }
    return true;
  }

  /** Whether this device has a microphone the page may use; the reason when not. */
  async checkMicrophone() {
    const win = this.win;
    let why = "";
    if (!win.isSecureContext) {
      why = "the microphone needs a secure page: open the console's https:// address";
    } else if (!win.navigator.mediaDevices?.getUserMedia) {
      why = "this browser gives the page no microphone";
    } else if (win.navigator.mediaDevices.enumerateDevices) {
      try {
        const devices = await win.navigator.mediaDevices.enumerateDevices();
        if (!devices.some((d) => d.kind === "audioinput")) why = "no microphone is connected";
      } catch {
        /* unknown: getUserMedia will say */
      }
    }
    this.micWhy = why;
    this.showEngine();
  }

  /** Why hands-free cannot be switched on now, or "" when it can. */
  handsfreeWhy() {
    if (!this.allowed) return this.deniedWhy || "only the pilot holding the controls may speak commands";
    if (this.micWhy) return this.micWhy;
    if (this.engine !== "server") return "hands-free listens with this console's recogniser (Recogniser: server or auto)";
    return "";
  }

  get engine() {
    if (this.setting === "auto" && this.browserFailed) return "server";
    return chooseEngine(this.setting, this.win);
  }

  setSetting(value) {
    if (!ENGINES.includes(value)) return;
    if (this.listening) this.stop();
    this.setting = value;
    this.win.localStorage?.setItem(STORE_KEY, value);
    this.showEngine();
  }

  /** The page says which recogniser is listening (or would listen). */
  showEngine() {
    const engine = this.engine;
    document.body.dataset.recognizer = engine;
    if (this.els.label) {
      this.els.label.textContent =
        engine === "server" ? "Speech: this console (offline)" : "Speech: the browser's (online)";
    }
    if (this.els.handsfree) {
      const why = this.handsfreeWhy();
      this.els.handsfree.disabled = Boolean(why);
      this.els.handsfree.title = why ? `Hands-free is unavailable: ${why}.` : "Listen continuously";
      const note = document.getElementById("handsfree-why");
      if (note) note.textContent = why ? `Hands-free unavailable: ${why}.` : "";
    }
    // Over HTTPS with the console's own CA, offer its certificate so a phone can trust it once.
    const ca = document.getElementById("ca-download");
    if (ca) ca.hidden = this.win.location.protocol !== "https:";
  }

  /** Whether this console may speak commands now (``why``: the reason when not); hands-free
   *  stops when it may not. */
  setAllowed(allowed, why = "") {
    this.allowed = allowed;
    this.deniedWhy = why;
    if (!allowed && this.listening) this.stop();
    this.showEngine();
  }

  /** Button down or M down: start; a long hold is push-to-talk, a tap toggles. Hands-free,
   *  while the console speaks, it interrupts the reply instead (barge-in by intent). */
  press() {
    if (this.listening && this.engine === "server" && this.server.muted) {
      this.pressedAt = 0;
      this.opts.hush?.(); // the console stops speaking
      this.server.interrupt();
      return;
    }
    if (this.listening) {
      this.pressedAt = 0;
      this.stop();
      return;
    }
    this.pressedAt = Date.now();
    this.start("ptt");
  }

  release() {
    if (!this.pressedAt) return;
    const held = Date.now() - this.pressedAt;
    this.pressedAt = 0;
    if (held >= HOLD_MS && this.listening) this.stop();
  }

  toggle() {
    this.press();
  }

  start(mode) {
    if (this.engine === "browser") {
      this.browser.start();
      if (this.browser.listening) this.setListening(true, "browser");
      return;
    }
    this.server.mode = mode;
    this.listening = true; // starting: a second press stops; the indicator waits for the mic
    this.els.interim.textContent = "Starting the microphone…";
    this.server.start(mode).then((ok) => {
      if (!ok) this.setListening(false);
    });
  }

  stop() {
    if (this.engine === "browser") this.browser.stop();
    else this.server.stop();
    if (this.els.handsfree) this.els.handsfree.checked = false;
    this.setListening(false);
  }

  onHandsfree() {
    if (this.listening) this.stop();
    if (this.els.handsfree.checked) {
      this.pressedAt = 0;
      this.start("handsfree");
      if (this.els.handsfree) this.els.handsfree.checked = true;
    }
  }

  setListening(on, engine = this.engine) {
    this.listening = on;
    const b = this.els.button;
    b.setAttribute("aria-pressed", String(on));
    b.setAttribute("aria-label", on ? "Stop listening (M)" : "Speak a command: hold, or tap (M)");
    document.body.dataset.listening = on ? engine : "";
    if (on && (!this.els.interim.textContent || this.els.interim.textContent.startsWith("Starting"))) {
      this.els.interim.textContent = engine === "server" ? "Listening (this console)…" : "Listening…";
    }
    if (!on && /^(Listening|Starting)/.test(this.els.interim.textContent)) this.els.interim.textContent = "";
  }
}
