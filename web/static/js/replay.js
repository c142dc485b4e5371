// Replay timeline: play/pause, seek and speed of a recorded flight, read-only.
//
// Two ways in: the live console's Recordings menu opens ``/?replay=FLIGHT_ID`` (the running
// console replays it: every REST call goes to /api/v1/replays/FLIGHT_ID/…, rosbridge to
// …/rosbridge, a graph of its own where nothing flies: server/recorder/replay_live.py), or
// ``uav-console replay FILE.mcap`` serves the console on one recording. Either way the bar is
// shown only when the drones say ``replay: true``; the server plays the recording onto the
// graph, so every panel listens as it does live; this bar drives the timeline
// (POST …/replay {action: play|pause|seek|speed, position_s, speed}) and keeps the
// recording's clock, which the dialog and the alarms use for their times.

const POLL_MS = 500;
// Flight ids as the recorder makes them (server/recorder/index.py): nothing else is asked for.
const FLIGHT_ID = /^\d{8}T\d{6}Z(?:-\d+)?$/;

/** The flight this page replays (``?replay=ID``), or null for the live console. */
export function pageReplay(loc = window.location) {
  const id = new URLSearchParams(loc.search).get("replay");
  return id && FLIGHT_ID.test(id) ? id : null;
}

/** The REST base of a flight's replay in the running console. */
export function replayApiBase(id) {
  return `/api/v1/replays/${encodeURIComponent(id)}`;
}

/** The rosbridge URL of a flight's replay: no token in it, the handshake carries the
 *  console's HttpOnly cookie (server/recorder/replay_live.py admits it). */
export function replayRosbridgeUrl(location, id) {
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  return `${scheme}//${location.host}${replayApiBase(id)}/rosbridge`;
}

/** The page that replays ``id`` (the token stays in this tab's storage, not in the URL). */
export function replayPageUrl(id) {
  return `/?replay=${encodeURIComponent(id)}`;
}

/** "m:ss" of a number of seconds. */
export function clock(seconds) {
  const s = Math.max(0, Math.floor(seconds || 0));
  return `${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}`;
}

export class ReplayBar {
  /**
   * @param {import("./api.js").Api} api
   * @param {HTMLElement} root the #replay-bar element (hidden until a replay answers)
   * @param {() => void} onSeek called after a seek (e.g. to clear the map's trail)
   */
  constructor(api, root, onSeek = () => {}) {
    this.api = api;
    this.root = root;
    this.onSeek = onSeek;
    this.status = null;
    this.polledAt = 0; // performance.now() when ``status`` came
    this.active = false;
    this.dragging = false;
    this.button = root.querySelector("#replay-play");
    this.range = root.querySelector("#replay-seek");
    this.label = root.querySelector("#replay-time");
    this.speed = root.querySelector("#replay-speed");
    this.button.addEventListener("click", () =>
      this.send({ action: this.status?.playing ? "pause" : "play" }),
    );
    this.range.addEventListener("input", () => {
      this.dragging = true;
      this.render({ ...this.status, position_s: Number(this.range.value) });
    });
    this.range.addEventListener("change", async () => {
      this.dragging = false;
      await this.send({ action: "seek", position_s: Number(this.range.value) });
      this.onSeek();
    });
    this.speed.addEventListener("change", () =>
      this.send({ action: "speed", speed: Number(this.speed.value) }),
    );
  }

  /** True (and the bar shown, polling) when the server is a replay. */
  async start() {
    try {
      // A replay's drones say so; a live server is never asked for /replay (no 404 logged).
      const drones = await this.api.get("/drones");
      if (!Array.isArray(drones) || !drones.some((d) => d?.replay === true)) return false;
      this.render(await this.api.get("/replay"));
    } catch {
      return false;
    }
    this.root.hidden = false;
    this.active = true;
    document.body.dataset.replay = "1";
    setInterval(() => this.poll(), POLL_MS);
    return true;
  }

  /**
   * The recording's clock: Unix seconds of the moment being replayed now (null before the
   * first answer). Between two polls it runs on at the replay's speed while playing.
   */
  now() {
    const st = this.status;
    if (!st || !Number.isFinite(st.start_ns)) return null;
    let pos = Number(st.position_s) || 0;
    if (st.playing) pos += ((performance.now() - this.polledAt) / 1000) * (Number(st.speed) || 1);
    return st.start_ns / 1e9 + Math.min(pos, Number(st.duration_s) || pos);
  }

  async poll() {
    try {
      this.render(await this.api.get("/replay"));
    } catch {
      // server gone: the connection pill says so
    }
  }

  async send(body) {
    try {
      this.render(await this.api.post("/replay", body));
    } catch (err) {
      console.warn("replay control failed", err);
    }
  }

  render(st) {
    if (!st) return;
    this.status = st;
    this.polledAt = performance.now();
    const playing = Boolean(st.playing);
    this.button.textContent = playing ? "Pause" : "Play";
    this.button.setAttribute("aria-pressed", String(playing));
    this.range.max = String(st.duration_s ?? 0);
    if (!this.dragging) this.range.value = String(st.position_s ?? 0);
    this.label.textContent = `${clock(st.position_s)} / ${clock(st.duration_s)}`;
    if (st.speed && document.activeElement !== this.speed) this.speed.value = String(st.speed);
    this.root.title = st.file ? `Replaying ${st.file}` : "Replay";
  }
}
