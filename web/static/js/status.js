// The always-visible status bar (as QGroundControl and Foxglove keep one): selected drone,
// flight state, battery, link, task with its next step, the connection, and the health of both
// roads a stop takes (the web server and the drone's safety door). One function names
// flight states for every panel (status bar, telemetry, map, fleet list), so labels agree.
//
// When the server goes silent the bar greys out and says how old its values are and since
// when (the page's one rule, freshness.js); after a reconnect the console compares what it knew
// before with what the server says now and tells the operator what was lost (a task or patrol
// that no longer runs, a drone that landed or stopped).

import { ageText } from "./freshness.js";
import { setLevel, setText } from "./util.js";

// DESIGN §5 / Settings defaults (battery_low_pct 25, battery_critical_pct 12).
const BATTERY_LOW_PCT = 25;
const BATTERY_CRITICAL_PCT = 12;

/** ctrl_state names (VehicleSnapshot / ardrone navdata major states) -> operator words. */
const FLIGHT_WORDS = Object.freeze({
  DEFAULT: "Unknown",
  INIT: "Starting",
  INITED: "Starting",
  LANDED: "Landed",
  FLYING: "Flying",
  HOVERING: "Hovering",
  TEST: "Test",
  TAKEOFF: "Taking off",
  GOTOFIX: "Flying",
  LANDING: "Landing",
  LOOPING: "Flying",
});
const NAVDATA_STATES = ["DEFAULT", "INIT", "LANDED", "FLYING", "HOVERING", "TEST", "TAKEOFF", "GOTOFIX", "LANDING", "LOOPING"];

/**
 * The one flight-state label of the console.
 * @param {string|number|null} ctrl ctrl_state name (REST) or navdata state number
 * @param {{emergency?: boolean, link?: boolean|null}} flags
 */
export function flightLabel(ctrl, { emergency = false, link = null } = {}) {
  if (emergency) return "Emergency";
  if (link === false) return "Link lost";
  const name = typeof ctrl === "number" ? NAVDATA_STATES[ctrl] : String(ctrl || "").toUpperCase();
  return FLIGHT_WORDS[name] ?? (name ? name.charAt(0) + name.slice(1).toLowerCase() : "–");
}

export function flightLevel(label) {
  if (label === "Emergency" || label === "Link lost") return "alert";
  if (label === "Taking off" || label === "Landing" || label === "Unknown") return "warn";
  return label === "–" ? "unknown" : "ok";
}

/** Task text with its next step: "goto · running 40 % — marker 3 · then 2 more". */
export function taskText(task) {
  if (!task || !task.name || task.state === "idle") {
    const queued = Number(task?.queued) || 0;
    return queued ? `idle · ${queued} queued` : "idle";
  }
  let text = `${task.name} · ${task.state || "?"}`;
  if (Number.isFinite(task.progress) && task.progress > 0 && task.progress < 1) {
    text += ` ${Math.round(task.progress * 100)} %`;
  }
  if (task.detail) text += ` — next: ${task.detail}`;
  const queued = Number(task.queued) || 0;
  if (queued) text += ` · then ${queued} more`;
  return text;
}

/** What the operator lost while disconnected (sentences; empty when nothing changed). */
export function lostWhileAway(before, after) {
  const out = [];
  if (!before || !after) return out;
  const was = before.task && before.task.name && before.task.state !== "idle" ? before.task.name : "";
  const now = after.task && after.task.name && after.task.state !== "idle" ? after.task.name : "";
  if (was && was !== now) {
    out.push(`The ${was === "patrol" ? "patrol" : `“${was}” task`} no longer runs${now ? ` (now: ${now})` : ""}.`);
  }
  if (before.flight !== after.flight && before.flight && after.flight) {
    out.push(`The drone went from ${before.flight.toLowerCase()} to ${after.flight.toLowerCase()}.`);
  }
  if (before.drone && after.drone && before.drone !== after.drone) {
    out.push(`Drone ${before.drone} is no longer on this server; now commanding ${after.drone}.`);
  }
  return out;
}

export class StatusBar {
  constructor(root, now = () => new Date()) {
    this.$ = (id) => root.querySelector(`#${id}`);
    this.now = now;
    this.view = { drone: "", flight: "", battery: null, task: null, link: null };
    this.staleSince = null;
  }

  setDrone(name) {
    this.view.drone = name;
    setText(this.$("sb-drone-v"), name || "–");
  }

  setFlight(label) {
    this.view.flight = label;
    setText(this.$("sb-flight-v"), label);
    setLevel(this.$("sb-flight"), flightLevel(label));
  }

  setBattery(pct) {
    if (!Number.isFinite(pct)) return;
    this.view.battery = pct;
    setText(this.$("sb-battery-v"), `${Math.round(pct)} %`);
    const level = pct <= BATTERY_CRITICAL_PCT ? "alert" : pct <= BATTERY_LOW_PCT ? "warn" : "ok";
    setLevel(this.$("sb-battery"), level);
  }

  setLink(text, level) {
    this.view.link = text;
    setText(this.$("sb-link-v"), text);
    setLevel(this.$("sb-link"), level);
  }

  /**
   * The two roads a stop takes to the selected drone: the web server and the drone's safety
   * door, each {text, level} (level "ok", "alert", or "unknown" for a road there is not).
   */
  setRoads(server, door) {
    this.view.roads = { server: server.text, door: door.text };
    setText(this.$("sb-server-v"), server.text);
    setLevel(this.$("sb-server"), server.level);
    setText(this.$("sb-door-v"), door.text);
    setLevel(this.$("sb-door"), door.level);
    const levels = [server.level, door.level];
    const worst = levels.includes("alert") ? "alert" : server.level === "ok" ? "ok" : "unknown";
    setLevel(this.$("sb-roads"), worst);
  }

  setTask(task) {
    this.view.task = task;
    const text = taskText(task);
    setText(this.$("sb-task-v"), text);
    this.$("sb-task").title = `Task: ${text}`;
  }

  /** A copy of what the bar shows (to compare across a reconnection). */
  snapshot() {
    return JSON.parse(JSON.stringify(this.view));
  }

  /** Connection lost: remember what was shown, to tell what changed once it is back. */
  markStale() {
    if (this.staleSince) return;
    this.staleSince = this.now();
  }

  markFresh() {
    this.staleSince = null;
  }

  /** The server's silence (freshness.js): the bar greys out (data-stale, set by the rule) and
   *  says how old its values are and since when; null hides it. */
  showAge(ageS) {
    const el = this.$("sb-stale");
    if (ageS === null) {
      el.hidden = true;
      return;
    }
    const since = new Date(this.now().getTime() - ageS * 1000);
    const t = since.toLocaleTimeString([], { hour12: false });
    setText(el, `${ageText(ageS)} · no word from the server since ${t}`);
    el.title = el.textContent;
    el.hidden = false;
  }
}
