// Dialog panel: the conversation (newest at the bottom), each utterance annotated with how the
// server understood it; replies spoken with speechSynthesis unless muted, alerts also announced
// assertively for screen readers.

const MAX_ENTRIES = 200;
const MAX_SENT = 20; // own inputs awaiting their echo (a lost echo must not hide later ones forever)
// A second drone's reply to the same sentence ("all drones land") joins the operator's line
// when it comes this soon after the first; later it is another console's.
export const SAME_COMMAND_MS = 10000;
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

/** "12:03:04" of Unix seconds, in local time. */
export function clockText(unixS) {
  const d = new Date(unixS * 1000);
  if (Number.isNaN(d.getTime())) return "";
  return d.toLocaleTimeString([], { hour12: false });
}

/** A reply's text without the drone's name in front ("uav1: Taking off." → "Taking off."):
 *  the line's tag says which drone, once. */
export function withoutDrone(text, drone) {
  if (!drone || typeof text !== "string") return text || "";
  const m = new RegExp(`^${drone.replace(/[.*+?^${}()|[\]\\]/g, "\\$&")}\\s*[:,]\\s*`, "i").exec(text);
  return m ? text.slice(m[0].length) : text;
}

/** The drone a typed sentence names itself ("uav2 land", "drone 2, …", "all drones …"), or
 *  null: then it goes to the selected drone and its line says so. */
export function namedTarget(text) {
  const t = String(text || "").toLowerCase();
  if (/\b(all|every|both)\s+(the\s+)?drones?\b|\beveryone\b|\bfleet\b/.test(t)) return "all";
  const m = /\b(?:uav\s?|drone\s)(\d+)\b/.exec(t);
  return m ? `uav${m[1]}` : null;
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

/** Unix seconds of a reply's header stamp, or undefined (the line takes "now"). */
function replyTime(msg) {
  const s = msg?.header?.stamp;
  if (!s) return undefined;
  const sec = s.sec ?? s.secs;
  const nsec = s.nanosec ?? s.nsecs ?? 0;
  return typeof sec === "number" && sec > 0 ? sec + nsec / 1e9 : undefined;
}

export class DialogPanel {
  /**
   * @param {{log: HTMLElement, alerts: HTMLElement, mute: HTMLButtonElement, state: HTMLElement,
   *          voiceNote?: HTMLElement}} els
   * @param {{speechSynthesis?: SpeechSynthesis, storage?: Storage,
   *          serverSpeak?: (text: string) => Promise<boolean>,
   *          onAnswer?: (answer: "yes" | "no", drone: string) => boolean,
   *          now?: () => number, replay?: () => boolean}} env
   *   ``now``: Unix seconds of "now" for the lines' times (a replay's: the recording's);
   *   ``replay``: the log is a recording's (what the operator said is theirs, not another
   *   console's)
   */
  constructor(els, env = {}) {
    this.els = els;
    this.now = env.now ?? (() => Date.now() / 1000);
    this.replay = env.replay ?? (() => false);
    this.fleet = false; // several drones: each line says which drone
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

  /** Several drones: every line names its drone (a tag), and the operator's its target. */
  setFleet(fleet) {
    this.fleet = Boolean(fleet);
  }

  add(kind, text, extra = {}) {
    // div entries in a div role=log: a log is not a list (axe: listitem outside a list).
    const li = document.createElement("div");
    li.className = `msg msg-${kind}`;
    const at = Number.isFinite(extra.at) ? extra.at : this.now();
    const time = document.createElement("time");
    time.className = "at";
    time.dateTime = new Date(at * 1000).toISOString();
    time.textContent = clockText(at);
    li.append(time);
    li.dataset.at = String(at);
    if (extra.who) {
      const who = document.createElement("span");
      who.className = "who";
      who.textContent = extra.who;
      li.append(who);
      li.dataset.drone = extra.drone ?? extra.who;
    }
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
   *  comes); its copy on /console/utterance is then not shown again. ``opts`` as
   *  showUtterance's. */
  addUtterance(text, opts = {}) {
    this.sent.push(text);
    this.sent.splice(0, this.sent.length - MAX_SENT);
    return this.showUtterance(text, opts);
  }

  /** uav_console/Utterance: an input from any door (in a replay: the operator's, as
   *  recorded); this page's own are already shown. */
  onUtterance(msg) {
    const own = this.sent.indexOf(msg.text);
    if (own >= 0) {
      this.sent.splice(own, 1);
      return;
    }
    this.showUtterance(msg.text, { source: msg.source, confidence: msg.confidence, drone: msg.drone });
  }

  /**
   * One line of what an operator said (annotated when the reply comes). ``drone``: the
   * selected drone it goes to when the sentence names none (fleets); ``at``: when (default:
   * the page's now, a replay's recording time).
   */
  showUtterance(text, { source = "text", confidence = 1, drone = "", at } = {}) {
    let meta =
      source === "speech"
        ? `spoken · confidence ${Math.round(confidence * 100)} %`
        : source === "map"
          ? "from the map"
          : source === "button"
            ? "answered with a button"
            : source === "rest" || source === "rosbridge"
              ? `sent over ${source === "rest" ? "REST" : "rosbridge"}`
              : "typed";
    if (this.replay()) meta = `operator · ${meta}`;
    const named = namedTarget(text);
    const who = this.fleet && !named && drone ? `→ ${drone}` : "";
    const li = this.add("user", text, { meta, at, who, drone: named || drone });
    li.dataset.utterance = text;
    li.dataset.pending = "1";
    return li;
  }

  /** Empty the log (a replay jumped in time: what was shown belongs to another moment). */
  clear() {
    this.els.log.replaceChildren();
  }

  addSystem(text, at) {
    return this.add("system", text, { at });
  }

  /**
   * uav_console/Reply: text, level, speak, utterance, commands (JSON string), expects, drone,
   * header (its stamp is the line's time: a replay shows the recording's).
   */
  onReply(msg) {
    const level = msg.level || "info";
    const commands = parseCommands(msg.commands);
    const drone = msg.drone || "";
    const at = replyTime(msg);
    if (msg.utterance) this.annotate(msg.utterance, commands, drone, at);
    // Any later reply of the same drone settles (or replaces) the question it asked.
    if (msg.utterance || msg.expects) this.closeQuestions(drone);
    const text = this.fleet ? withoutDrone(msg.text || "", drone) : msg.text || "";
    const folded = this.fold(drone, text, level, msg, at);
    if (folded) return folded;
    const who = this.fleet && drone ? drone : "";
    const li = this.add("bot", text, { level, at, who, drone });
    li.dataset.level = level;
    li.dataset.reply = text;
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

  /**
   * The same state line again from the same drone ("Hovering" ×12): counted on the line it
   * repeats, which moves to the bottom with the new time, and not spoken again. Only plain
   * information folds, and only while the operator said nothing since; alarms, questions and
   * answers to a command always get their own line.
   */
  fold(drone, text, level, msg, at) {
    if (level !== "info" || msg.utterance || msg.expects || !text) return null;
    let last = null;
    for (let el = this.els.log.lastElementChild; el; el = el.previousElementSibling) {
      if (el.classList.contains("msg-user")) return null;
      if (el.classList.contains("msg-bot") && (el.dataset.drone || "") === drone) {
        last = el;
        break;
      }
    }
    if (!last || last.dataset.reply !== text || last.dataset.level !== "info") return null;
    if (last.querySelector(".answers")) return null;
    const count = Number(last.dataset.count || "1") + 1;
    last.dataset.count = String(count);
    let times = last.querySelector(".count");
    if (!times) {
      times = document.createElement("span");
      times.className = "count";
      last.querySelector(".text").after(times);
    }
    times.textContent = ` ×${count}`;
    const time = last.querySelector("time.at");
    time.dateTime = new Date(at * 1000).toISOString();
    time.textContent = clockText(at);
    last.dataset.at = String(at);
    const log = this.els.log;
    const stick = log.scrollHeight - log.scrollTop - log.clientHeight < 40;
    log.append(last); // newest at the bottom
    if (stick) last.scrollIntoView({ block: "end" });
    return last;
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

  /**
   * Attach "understood: …" to the operator's line this reply answers: the newest pending one
   * with this text, or the one another drone answered a moment ago ("all drones land": one
   * line, both drones' understanding). Otherwise the sentence came from another console (in a
   * replay: from the operator) and gets its own line.
   */
  annotate(utterance, commands, drone = "", at = undefined) {
    const users = [...this.els.log.querySelectorAll(".msg-user")].reverse();
    const mine = (el) => el.dataset.utterance === utterance;
    let li = users.find((el) => mine(el) && el.dataset.pending === "1");
    if (!li && drone) {
      const now = performance.now();
      li = users.find(
        (el) =>
          mine(el) &&
          now - Number(el.dataset.answeredAt || -Infinity) < SAME_COMMAND_MS &&
          !(el.dataset.answeredBy || "").split(" ").includes(drone),
      );
    }
    if (!li) {
      const meta = this.replay() ? "operator" : "from another console";
      li = this.add("user", utterance, { meta, at, drone });
    }
    li.dataset.pending = "0";
    li.dataset.answeredAt = String(performance.now());
    const by = (li.dataset.answeredBy || "").split(" ").filter(Boolean);
    if (drone && !by.includes(drone)) by.push(drone);
    li.dataset.answeredBy = by.join(" ");
    const words = commands ? `understood: ${describeCommands(commands)}` : "understood: —";
    const same = [...li.querySelectorAll(".understood")].find((u) => u.dataset.words === words);
    const u = same || document.createElement("span");
    if (!same) {
      u.className = "understood";
      u.dataset.words = words;
      u.dataset.drones = "";
      li.append(u);
    }
    const drones = (u.dataset.drones || "").split(" ").filter(Boolean);
    if (drone && !drones.includes(drone)) drones.push(drone);
    u.dataset.drones = drones.join(" ");
    u.textContent = this.fleet && drones.length ? `${words} · ${drones.join(", ")}` : words;
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
