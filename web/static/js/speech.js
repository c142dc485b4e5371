// Speech input with the Web Speech API (SpeechRecognition / webkitSpeechRecognition): interim
// text shown while speaking, the final text handed on with its confidence.

export function recognitionClass(win = window) {
  return win.SpeechRecognition || win.webkitSpeechRecognition || null;
}

export class SpeechInput {
  /**
   * @param {{button: HTMLButtonElement, interim: HTMLElement}} els
   * @param {(text: string, confidence: number) => void} onFinal
   * @param {(text: string) => void} onNotice message for the operator (unsupported, errors)
   * @param {(code: string) => boolean} [onError] told every engine error first (its
   *   SpeechRecognitionErrorEvent code, or "start-failed"); true when it handled the error
   *   (voice.js falls back to the offline recogniser), and no notice is shown
   */
  constructor(els, onFinal, onNotice, win = window, onError = null) {
    this.els = els;
    this.onFinal = onFinal;
    this.onNotice = onNotice;
    this.onError = onError;
    this.Recognition = recognitionClass(win);
    this.rec = null;
    this.listening = false;
    els.button.addEventListener("click", () => this.toggle());
    if (!this.Recognition) {
      els.button.title = "Speech recognition is not available in this browser";
      els.button.dataset.unsupported = "1";
    }
  }

  get supported() {
    return !!this.Recognition;
  }

  toggle() {
    if (this.listening) this.stop();
    else this.start();
  }

  start() {
    if (!this.Recognition) {
      this.onNotice(
        "This browser has no speech recognition. Type your command instead (Chrome, Edge and Safari support speech).",
      );
      return;
    }
    if (this.listening) return;
    const rec = new this.Recognition();
    rec.lang = "en-US";
    rec.continuous = false;
    rec.interimResults = true;
    rec.maxAlternatives = 1;
    rec.onresult = (ev) => this.onResult(ev);
    rec.onerror = (ev) => {
      const why = ev.error || "error";
      if (this.onError?.(why)) return;
      if (why === "no-speech") this.onNotice("I heard nothing. Press the microphone and speak.");
      else if (why === "not-allowed" || why === "service-not-allowed")
        this.onNotice("Microphone permission was refused. Allow it in the browser, or type instead.");
      else if (why !== "aborted") this.onNotice(`Speech recognition failed (${why}). Type instead.`);
    };
    rec.onend = () => this.setListening(false);
    this.rec = rec;
    try {
      rec.start();
      this.setListening(true);
      this.els.interim.textContent = "Listening…";
    } catch (err) {
      this.setListening(false);
      if (!this.onError?.("start-failed")) {
        this.onNotice(`Speech recognition could not start: ${err.message || err}`);
      }
    }
  }

  stop() {
    if (this.rec) this.rec.stop();
  }

  setListening(on) {
    this.listening = on;
    this.els.button.setAttribute("aria-pressed", String(on));
    this.els.button.setAttribute("aria-label", on ? "Stop listening (M)" : "Speak a command (M)");
    if (!on && this.els.interim.textContent === "Listening…") this.els.interim.textContent = "";
  }

  onResult(ev) {
    let interim = "";
    for (let i = ev.resultIndex ?? 0; i < ev.results.length; i += 1) {
      const result = ev.results[i];
      const alt = result[0];
      if (!alt) continue;
      if (result.isFinal) {
        this.els.interim.textContent = "";
        const text = String(alt.transcript || "").trim();
        // An engine that gives no confidence is not trusted more than a low one: pass 0 on and
        // let the dialog manager ask to repeat (it owns the threshold, Settings.confidence_threshold).
        const confidence = Number.isFinite(alt.confidence) ? alt.confidence : 0;
        if (text) this.onFinal(text, confidence);
      } else {
        interim += alt.transcript;
      }
    }
    if (interim) this.els.interim.textContent = `“${interim.trim()}…”`;
  }
}
