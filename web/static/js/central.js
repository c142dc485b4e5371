// The Central patrol (CTANS): start, watch, resume and end a persistent patrol of the whole
// fleet from the console, with live coverage and the mission's state as the server has it
// (server/fleet/states.py): waiting, running, paused by the operator (Land, Hover, Emergency
// or a jog on one of its drones; Resume or End then), stalled, ended.
//
// Self-contained: it needs only the #central block of the page and the REST API
// (GET/POST/DELETE /api/v1/patrol, server/fleet/central.py). Voice does the same through the
// dialog ("start the patrol with all drones", "resume the patrol", "end the patrol").

import { Api, ApiError } from "./api.js";
import { pageToken } from "./session.js";

const POLL_MS = 1000;

/** Seconds as "42 s" or "3 min 05 s". */
export function ago(s) {
  if (s === null || s === undefined || !Number.isFinite(s)) return "–";
  if (s < 90) return `${Math.round(s)} s`;
  const m = Math.floor(s / 60);
  return `${m} min ${String(Math.round(s - 60 * m)).padStart(2, "0")} s`;
}

export class CentralPanel {
  /**
   * @param {HTMLElement} root the #central block; @param {Api} api
   * @param {() => (string|null)} lease the pilot lease key this page holds, if any
   */
  constructor(root, api, lease = () => null) {
    this.root = root;
    this.api = api;
    this.lease = lease;
    this.$ = (id) => root.querySelector(`#${id}`);
    this.busy = false;
    this.$("central-start").addEventListener("click", () => this.act("POST", "Starting…"));
    this.$("central-resume").addEventListener("click", () =>
      this.act("POST", "Resuming…", { action: "resume" }),
    );
    this.$("central-stop").addEventListener("click", () => this.act("DELETE", "Stopping…"));
    this.timer = null;
    this.last = null;
    // the page's role arrives over rosbridge (app.js marks it on <body>): re-apply the buttons
    new MutationObserver(() => this.last && this.render(this.last)).observe(document.body, {
      attributes: true,
      attributeFilter: ["data-role"],
    });
  }

  start() {
    this.poll();
    this.timer = setInterval(() => this.poll(), POLL_MS);
  }

  say(text, level = "info") {
    const el = this.$("central-reply");
    el.textContent = text;
    el.dataset.level = level;
  }

  async act(method, pending, body = {}) {
    if (this.busy) return;
    this.busy = true;
    this.say(pending);
    try {
      // Starting a patrol needs the pilot lease: the page's rosbridge session holds
      // it, and REST names the holding's key in X-Pilot-Lease, as app.js's own requests do.
      const key = this.lease();
      const headers = key ? { "X-Pilot-Lease": key } : {};
      const out = await this.api.request(method, "/patrol", method === "POST" ? body : undefined, {
        headers,
      });
      this.say(out.reply);
      this.render(out);
    } catch (err) {
      this.say(err instanceof ApiError ? err.message : String(err), "warn");
    } finally {
      this.busy = false;
    }
  }

  async poll() {
    try {
      this.render(await this.api.get("/patrol", { timeoutMs: 3000 }));
    } catch (err) {
      if (!(err instanceof ApiError) || err.status !== 0) this.say(err.message, "warn");
    }
  }

  /**
   * GET /patrol: {running, state, mission: {id, state, detail, drones, active, relief,
   * handoffs, coverage: {waypoints, longest_gap_s, lap_s, route: {coverage_pct,
   * longest_gap_s, gaps, …}}}, drones}; ``state`` is "none" with no live mission.
   */
  render(status) {
    this.last = status;
    const m = status.mission;
    const live = Boolean(m) && status.state !== "none";
    const running = Boolean(status.running && m);
    const paused = live && status.state === "paused";
    // a patrol started elsewhere (voice, REST, another console) opens the panel once
    if (live && this.root.dataset.live !== "true") this.root.open = true;
    this.root.dataset.running = String(running);
    this.root.dataset.live = String(live);
    this.root.dataset.state = live ? status.state : "none";
    // observers watch (app.js marks the page's role on <body>); the server checks anyway
    const observer = document.body.dataset.role === "observer";
    const start = this.$("central-start");
    const resume = this.$("central-resume");
    start.hidden = paused;
    resume.hidden = !paused;
    start.disabled = live || observer;
    resume.disabled = !paused || observer;
    this.$("central-stop").disabled = !live || observer;
    this.$("central-state").textContent = live ? missionLine(m) : "not running";
    const cov = live ? m.coverage : null;
    const route = cov ? cov.route : null;
    this.$("central-coverage").textContent = coverageText(route);
    this.$("central-cov-gap").textContent =
      route && route.coverage !== null ? seconds(route.longest_gap_s) : "–";
    this.$("central-handoffs").textContent = live ? String(m.handoffs) : "–";
    this.$("central-gap").textContent = cov ? ago(cov.longest_gap_s) : "–";
    this.$("central-lap").textContent = cov && cov.lap_s !== null ? ago(cov.lap_s) : "–";
    const wps = this.$("central-waypoints");
    wps.replaceChildren(
      ...(cov ? cov.waypoints : []).map((w) => {
        const li = document.createElement("li");
        li.dataset.index = String(w.index);
        li.dataset.visited = String(w.visited);
        li.textContent = w.visited
          ? `WP ${w.index + 1}: ${ago(w.since_last_s)} ago`
          : `WP ${w.index + 1}: not yet`;
        return li;
      }),
    );
    const drones = this.$("central-drones");
    drones.replaceChildren(
      ...status.drones.map((d) => {
        const li = document.createElement("li");
        li.dataset.drone = d.name;
        li.dataset.role = d.role;
        const bat = d.battery === null ? "–" : `${Math.round(d.battery)} %`;
        li.textContent = `${d.name}: ${d.role}, battery ${bat}`;
        return li;
      }),
    );
  }
}

/**
 * Route coverage as "99.65 %" (the share of the time since a drone first reached the route
 * with a drone on it), "–" before one has.
 */
export function coverageText(route) {
  if (!route || route.coverage_pct === null || route.coverage_pct === undefined) return "–";
  return `${route.coverage_pct.toFixed(2)} %`;
}

/** A gap as "0 s", "12.7 s" or "3 min 05 s". */
export function seconds(s) {
  if (s === null || s === undefined || !Number.isFinite(s)) return "–";
  return s < 90 ? `${Math.round(10 * s) / 10} s` : ago(s);
}

/**
 * The mission in one line: "patrol1: paused by the operator (land) · uav1 was patrolling",
 * "patrol1: running: uav2 patrolling · 2 handoffs".
 */
export function missionLine(m) {
  const who = (m.drones || [])
    .filter((d) => d.was)
    .map((d) => `${d.name} was ${d.was}`)
    .join(", ");
  const handoffs = `${m.handoffs} handoff${m.handoffs === 1 ? "" : "s"}`;
  return `${m.id}: ${m.detail || m.state}${who ? ` · ${who}` : ""} · ${handoffs}`;
}

function boot() {
  const root = document.getElementById("central");
  if (!root) return;
  const token = pageToken();
  if (!token) return; // the console says why; nothing works without one
  // The lease is taken by the console (app.js, window.uavConsole) once its rosbridge is up.
  const lease = () => window.uavConsole?.api?.leaseHolder ?? null;
  const panel = new CentralPanel(root, new Api("/api/v1", token), lease);
  window.uavCentral = panel;
  panel.start();
}

if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", boot);
else boot();
