// Dialog panel: the conversation (newest at the bottom), each utterance annotated with how the
// server understood it; replies spoken with speechSynthesis unless muted, alerts also announced
// assertively for screen readers.

const MAX_ENTRIES = 200;
const MAX_SENT = 20; // own inputs awaiting their echo (a lost echo must not hide later ones forever)
// How long the Yes / No buttons of "Did you say …?" stay usable: the server drops the question
// after 15 s (server/dialog/confirm.py MAX_AGE_S), and a later yes would run nothing.
export const ANSWER_TTL_MS = 15000;

/** A short human reading of a command list (DESIGN §4 commands). */
export function describeCommands(commands) {
  if (!Array.isArray(commands) || commands.length === 0) return "nothing";
  return commands
    .map((c) => {
      const slots = Object.entries(c)
        .filter(([k]) => k !== "action")
        .map(([k, v]) => `${k}=${Array.isArray(v) ? v.join(",") : v}`);
      return slots.length ? `${c.action}(${slots.join(", ")})` : c.action;
    })
    .join(" → ");
}

function parseCommands(raw) {
  if (Array.isArray(raw)) return raw;
  if (typeof raw !== "string" || raw === "") return null;
  try {
    const v = JSON.parse(raw);
    return Array.isArray(v) ? v : null;
  } catch {
    return null;
  }
}

export class DialogPanel {
  /**
   * @param {{log: HTMLElement, alerts: HTMLElement, mute: HTMLButtonElement, state: HTMLElement,
   *          voiceNote?: HTMLElement}} els
   * @param {{speechSynthesis?: SpeechSynthesis, storage?: Storage,
   *          serverSpeak?: (text: string) => Promise<boolean>,
   *          onAnswer?: (answer: "yes" | "no", drone: string) => boolean}} env
   */
  constructor(els, env = {}) {
    this.els = els;
    this.synth = env.speechSynthesis ?? window.speechSynthesis ?? null;
    this.storage = env.storage ?? window.localStorage;
    this.serverSpeak = env.serverSpeak ?? null;
    this.onAnswer = env.onAnswer ?? null;
    this.muted = this.storage?.getItem("uavc.muted") === "1";
    // "browser" (speechSynthesis has voices), "server" (replies spoken by the server's
    // espeak-ng), "none" (shown, not spoken), or "unknown" until checked.
    this.voice = "unknown";
    this.sent = []; // texts this page sent whose /console/utterance copy has not come back yet
    els.mute.addEventListener("click", () => this.setMuted(!this.muted));
    this.renderMute();
  }

  /** Where spoken replies come from (see ``voice``); says so on the page. */
  setVoice(voice) {
    this.voice = voice;
    const note = this.els.voiceNote;
    if (note) {
      note.hidden = voice === "browser" || voice === "unknown";
      note.textContent =
        voice === "server"
          ? "This browser has no voices: replies are spoken by the server."
          : voice === "none"
            ? "This browser has no voices and the server has no speech engine: replies are shown, not spoken."
            : "";
    }
    this.renderMute();
  }

  setMuted(muted) {
    this.muted = muted;
    try {
      this.storage?.setItem("uavc.muted", muted ? "1" : "0");
    } catch {
      /* private mode: the toggle still works for this page */
    }
    if (muted && this.synth) this.synth.cancel();
    this.renderMute();
  }

  renderMute() {
    const b = this.els.mute;
    b.setAttribute("aria-pressed", String(this.muted));
    const label = this.muted
      ? "Muted"
      : this.voice === "none"
        ? "No voice"
        : this.voice === "server"
          ? "Server voice on"
          : this.voice === "unknown"
            ? "Voice…"
            : "Voice on";
    b.querySelector(".label").textContent = label;
    b.title = this.muted
      ? "Spoken replies are muted"
      : this.voice === "none"
        ? "No voice available: replies are shown only"
        : "Mute spoken replies";
    b.dataset.voice = this.voice;
  }

  add(kind, text, extra = {}) {
    // div entries in a div role=log: a log is not a list (axe: listitem outside a list).
    const li = document.createElement("div");
    li.className = `msg msg-${kind}`;
    const body = document.createElement("span");
    body.className = "text";
    body.textContent = text;
    li.append(body);
    if (extra.level) li.dataset.level = extra.level;
    if (extra.meta) {
      const meta = document.createElement("span");
      meta.className = "meta";
      meta.textContent = extra.meta;
      li.append(meta);
    }
    const log = this.els.log;
    const stick = log.scrollHeight - log.scrollTop - log.clientHeight < 40;
    log.append(li);
    while (log.children.length > MAX_ENTRIES) log.firstElementChild.remove();
    if (stick || kind === "user") li.scrollIntoView({ block: "end" });
    return li;
  }

  /** The operator said or typed something here (shown at once, annotated when the reply
   *  comes); its copy on /console/utterance is then not shown again. */
  addUtterance(text, opts = {}) {
    this.sent.push(text);
    this.sent.splice(0, this.sent.length - MAX_SENT);
    return this.showUtterance(text, opts);
  }

  /** uav_console/Utterance: an input from any door; this page's own are already shown. */
  onUtterance(msg) {
    const own = this.sent.indexOf(msg.text);
    if (own >= 0) {
      this.sent.splice(own, 1);
      return;
    }
    this.showUtterance(msg.text, { source: msg.source, confidence: msg.confidence });
  }

  showUtterance(text, { source = "text", confidence = 1 } = {}) {
    const meta =
      source === "speech"
        ? `spoken · confidence ${Math.round(confidence * 100)} %`
        : source === "map"
          ? "from the map"
          : source === "button"
            ? "answered with a button"
            : source === "rest" || source === "rosbridge"
              ? `sent over ${source === "rest" ? "REST" : "rosbridge"}`
              : "typed";
    const li = this.add("user", text, { meta });
    li.dataset.utterance = text;
    li.dataset.pending = "1";
    return li;
  }

  addSystem(text) {
    return this.add("system", text);
  }

  /** uav_console/Reply: text, level, speak, utterance, commands (JSON string), expects. */
  onReply(msg) {
    const level = msg.level || "info";
    const commands = parseCommands(msg.commands);
    if (msg.utterance) this.annotate(msg.utterance, commands);
    // Any later reply of the same drone settles (or replaces) the question it asked.
    if (msg.utterance || msg.expects) this.closeQuestions(msg.drone || "");
    const li = this.add("bot", msg.text || "", { level });
    li.dataset.level = level;
    if (msg.expects === "confirm" && this.onAnswer) this.addAnswers(li, msg.drone || "");
    if (this.els.lastReply) {
      this.els.lastReply.textContent = msg.text || "";
      this.els.lastReply.dataset.level = level;
    }
    if (level === "alert" || level === "warn") {
      this.els.alerts.textContent = "";
      // A fresh text node makes screen readers announce repeated alerts too.
      this.els.alerts.append(document.createTextNode(msg.text || ""));
    }
    if (msg.speak !== false && msg.text) this.speak(msg.text, level);
    return li;
  }

  /** Yes / No buttons under a "Did you say …?" reply: the answer goes to the drone that
   *  asked, whichever drone is selected now; usable once, and for ``ANSWER_TTL_MS``. */
  addAnswers(li, drone) {
    const row = document.createElement("span");
    row.className = "answers";
    row.setAttribute("role", "group");
    row.setAttribute("aria-label", "Answer the question");
    row.dataset.drone = drone;
    for (const answer of ["yes", "no"]) {
      const b = document.createElement("button");
      b.type = "button";
      b.className = "btn btn-small";
      b.dataset.answer = answer;
      b.textContent = answer === "yes" ? "Yes, do it" : "No";
      b.addEventListener("click", () => {
        if (this.onAnswer(answer, drone)) this.closeAnswers(row);
      });
      row.append(b);
    }
    li.append(row);
    row.timer = setTimeout(() => this.closeAnswers(row), ANSWER_TTL_MS);
  }

  closeAnswers(row) {
    clearTimeout(row.timer);
    for (const b of row.querySelectorAll("button")) b.disabled = true;
    row.dataset.closed = "1";
  }

  /** The drone whose "Did you say …?" is open when ``selected`` has none open (the newest), else
   *  "": a bare yes or no said or typed now answers it (Utterance.asked_by). */
  askedBy(selected) {
    const open = [...this.els.log.querySelectorAll(".answers:not([data-closed])")];
    if (open.some((row) => row.dataset.drone === selected)) return "";
    return open.length ? open[open.length - 1].dataset.drone : "";
  }

  /** Disable the open Yes / No buttons of ``drone``'s questions. */
  closeQuestions(drone) {
    for (const row of this.els.log.querySelectorAll(".answers:not([data-closed])")) {
      if (row.dataset.drone === drone) this.closeAnswers(row);
    }
  }

  /** Attach "understood as …" to the newest pending entry with this text (or add one). */
  annotate(utterance, commands) {
    const pending = [...this.els.log.querySelectorAll(".msg-user[data-pending='1']")];
    let li = pending.reverse().find((el) => el.dataset.utterance === utterance);
    if (!li) {
      li = this.add("user", utterance, { meta: "from another console" });
    }
    li.dataset.pending = "0";
    const u = document.createElement("span");
    u.className = "understood";
    u.textContent = commands ? `understood: ${describeCommands(commands)}` : "understood: —";
    li.append(u);
  }

  speak(text, level) {
    if (this.muted) return;
    if (this.voice === "server" && this.serverSpeak) {
      this.serverSpeak(text, level);
      return;
    }
    if (this.voice === "none" || !this.synth || typeof SpeechSynthesisUtterance === "undefined") return;
    const u = new SpeechSynthesisUtterance(text);
    u.lang = "en-US";
    if (level === "alert") {
      this.synth.cancel(); // an alert goes first
      u.rate = 1.1;
    }
    this.synth.speak(u);
  }

  onState(msg) {
    const grammars = Array.isArray(msg.grammars) ? msg.grammars.join(", ") : "";
    this.els.state.textContent = msg.state ? `· ${msg.state.toLowerCase().replace(/_/g, " ")}` : "";
    this.els.state.title = grammars ? `active grammars: ${grammars}` : "";
  }
}
