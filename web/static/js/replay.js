// Replay timeline: play/pause, seek and speed for `uav-console replay FILE.mcap`.
//
// Shown only when the server is a replay (its GET /api/v1/drones entries carry `replay: true`;
// a live console never asks for /replay and the bar stays hidden). The server plays the recording onto its graph, so every panel
// keeps listening to rosbridge as it does live; this bar only drives the timeline:
// POST /api/v1/replay {action: play|pause|seek|speed, position_s, speed}.

const POLL_MS = 500;

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
    document.body.dataset.replay = "1";
    setInterval(() => this.poll(), POLL_MS);
    return true;
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
