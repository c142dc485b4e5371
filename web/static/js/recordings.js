// Flight recordings in the top bar: a "● REC" pill while a flight is being recorded, and a
// "Recordings" menu listing GET /api/v1/flights with a download link (MCAP) and a Replay
// button for each: the replay opens in a tab of its own (replay.js), the live console stays.
//
// Downloads and replays carry no credential in their addresses: the browser sends the HttpOnly
// cookie the console's first load set (server/http/http_guard.py), with the download (streamed to
// disk, saved under the server's Content-Disposition name) and with the replay's rosbridge
// socket. A token in a URL would end up in history and logs.

import { replayPageUrl } from "./replay.js";

const POLL_MS = 5000;

/** "12.3 MB" / "850 kB" of a byte count. */
export function size(bytes) {
  const n = Number(bytes) || 0;
  return n >= 1e6 ? `${(n / 1e6).toFixed(1)} MB` : `${Math.max(1, Math.round(n / 1e3))} kB`;
}

/** "2026-11-23 08:35" of an ISO 8601 UTC time, in local time. */
export function when(iso) {
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return "–";
  const pad = (x) => String(x).padStart(2, "0");
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${pad(d.getHours())}:${pad(d.getMinutes())}`;
}

export class RecordingsMenu {
  /**
   * @param {import("./api.js").Api} api
   * @param {{pill: HTMLElement, menu: HTMLDetailsElement, list: HTMLElement}} els
   * @param {(url: string) => void} open opens a replay page (a new tab sharing this tab's
   *   session storage; its connections carry the console's cookie, no token in any address)
   */
  constructor(api, els, open = (url) => window.open(url, "_blank")) {
    this.api = api;
    this.els = els;
    this.open = open;
    this.flights = [];
    els.menu.addEventListener("toggle", () => {
      if (els.menu.open) this.poll();
    });
  }

  start() {
    this.els.menu.hidden = false;
    this.poll();
    setInterval(() => this.poll(), POLL_MS);
  }

  async poll() {
    try {
      const body = await this.api.get("/flights");
      this.render(Array.isArray(body?.flights) ? body.flights : []);
    } catch {
      // server away or recorder unavailable: keep what is shown
    }
  }

  render(flights) {
    this.flights = flights;
    const current = flights.find((f) => f.ended === null);
    this.els.pill.hidden = !current;
    if (current) this.els.pill.title = `Recording flight ${current.id}`;
    const list = this.els.list;
    list.replaceChildren();
    if (flights.length === 0) {
      const li = document.createElement("li");
      li.className = "muted";
      li.textContent = "No recordings yet: every flight is recorded.";
      list.append(li);
      return;
    }
    for (const f of [...flights].reverse()) {
      const li = document.createElement("li");
      li.dataset.id = f.id;
      const label = `${when(f.started)} · ${(f.drones || []).join(", ") || "–"} · ${size(f.bytes)}`;
      if (f.ended === null) {
        li.textContent = `${label} · recording…`;
      } else {
        const a = document.createElement("a");
        a.href = `/api/v1/flights/${encodeURIComponent(f.id)}`;
        a.download = `uav-console-${f.id}.mcap`;
        a.textContent = label;
        a.title = `${f.messages} messages; open in Foxglove or with uav-console replay`;
        const play = document.createElement("button");
        play.type = "button";
        play.className = "btn btn-small recording-replay";
        play.dataset.replay = f.id;
        play.textContent = "Replay";
        play.setAttribute("aria-label", `Replay the flight of ${label}`);
        play.addEventListener("click", () => {
          this.els.menu.open = false;
          this.open(replayPageUrl(f.id));
        });
        li.append(a, " ", play);
      }
      list.append(li);
    }
  }
}
