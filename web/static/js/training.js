// Training panel: a pilot holding the lease injects the simulator's faults into the selected
// drone (POST /api/v1/sim/{id}/fault, server/api/sim.py) to practise what the alarms ask of an
// operator: link loss, a battery that drains fast or drops at once, a wind gust, lost markers.
//
// Shown only where it means something: a pilot with the lease, a simulated drone, a live
// console (never for observers, real drones or a replay). docs/flying.md, "Training".

/** Wind directions, as the weather says them: where the wind comes *from*; the gust blows the
 *  other way. Map frame (docs/CONVENTIONS.md): x east, y north. */
export const WIND_FROM = {
  west: [1, 0],
  south: [0, 1],
  east: [-1, 0],
  north: [0, -1],
};

/**
 * The faults the panel offers: each a button and the one number it takes.
 * ``body(value, extra)`` is the REST body; ``say(value, extra)`` the words for the log.
 */
export const FAULTS = [
  {
    kind: "link_loss",
    label: "Link loss",
    unit: "s",
    value: 5,
    min: 1,
    max: 60,
    step: 1,
    body: (v) => ({ kind: "link_loss", duration_s: v }),
    say: (v) => `link loss for ${v} s`,
  },
  {
    kind: "battery_drain",
    label: "Battery drain",
    unit: "%/s",
    value: 1,
    min: 0.1,
    max: 1.5, // server/api/models.py: MAX_LEAK_PCT_S (the drone must believe the drop)
    step: 0.1,
    body: (v) => ({ kind: "battery_drain", drain_pct_s: v }),
    say: (v) => `battery draining ${v} %/s faster`,
  },
  {
    kind: "battery",
    label: "Battery cliff to",
    unit: "%",
    value: 20,
    min: 0,
    max: 100,
    step: 1,
    body: (v) => ({ kind: "battery", battery_pct: v }),
    say: (v) => `battery dropped to ${v} %`,
  },
  {
    kind: "wind",
    label: "Wind gust",
    unit: "m/s",
    value: 5,
    min: 1,
    max: 15,
    step: 1,
    wind: true,
    body: (v, from) => {
      const [ux, uy] = WIND_FROM[from] || WIND_FROM.west;
      return { kind: "wind", wind_mps: [ux * v, uy * v], duration_s: 3 };
    },
    say: (v, from) => `a ${v} m/s gust from the ${from} for 3 s`,
  },
  {
    kind: "lost_markers",
    label: "Lost markers",
    unit: "s",
    value: 10,
    min: 1,
    max: 120,
    step: 1,
    body: (v) => ({ kind: "lost_markers", duration_s: v }),
    say: (v) => `markers out of sight for ${v} s`,
  },
];

/** Whether the panel is offered (see the module comment). */
export function trainingAllowed({ role, lease, simulated, replay }) {
  return role === "pilot" && lease === true && simulated === true && !replay;
}

export class TrainingPanel {
  /**
   * @param {HTMLDetailsElement} root the panel (hidden until allowed)
   * @param {import("./api.js").Api} api
   * @param {{drone: () => string|null, role: () => string|null, lease: () => boolean|null,
   *          replay: () => boolean, say: (text: string) => void}} env
   */
  constructor(root, api, env) {
    this.root = root;
    this.api = api;
    this.env = env;
    this.simulated = new Map(); // drone -> true/false as GET /drones/{id} says
    this.body = root.querySelector(".training-body");
    this.status = root.querySelector(".training-status");
    this.inputs = new Map();
    for (const f of FAULTS) this.body.append(this.row(f));
    const clear = document.createElement("button");
    clear.type = "button";
    clear.className = "btn btn-small btn-quiet";
    clear.dataset.fault = "clear";
    clear.textContent = "Clear all faults";
    clear.addEventListener("click", () => this.inject({ kind: "clear" }, "all faults cleared"));
    this.body.append(clear);
    this.refresh();
  }

  row(f) {
    const row = document.createElement("div");
    row.className = "training-row";
    const btn = document.createElement("button");
    btn.type = "button";
    btn.className = "btn btn-small";
    btn.dataset.fault = f.kind;
    btn.textContent = f.label;
    const input = document.createElement("input");
    input.type = "number";
    input.min = String(f.min);
    input.max = String(f.max);
    input.step = String(f.step);
    input.value = String(f.value);
    input.dataset.fault = f.kind;
    input.setAttribute("aria-label", `${f.label} (${f.unit})`);
    const unit = document.createElement("span");
    unit.className = "muted";
    unit.textContent = f.unit;
    row.append(btn, input, unit);
    let from = null;
    if (f.wind) {
      from = document.createElement("select");
      from.setAttribute("aria-label", "Wind from");
      from.dataset.fault = "wind-from";
      for (const dir of Object.keys(WIND_FROM)) from.append(new Option(`from ${dir}`, dir));
      row.append(from);
    }
    this.inputs.set(f.kind, input);
    btn.addEventListener("click", () => {
      const v = Math.min(f.max, Math.max(f.min, Number(input.value) || f.value));
      input.value = String(v);
      const extra = from ? from.value : undefined;
      this.inject(f.body(v, extra), f.say(v, extra));
    });
    return row;
  }

  /** What GET /drones/{id} said of ``drone`` (``simulated``). */
  setSimulated(drone, simulated) {
    if (!drone) return;
    const v = simulated === true;
    if (this.simulated.get(drone) === v) return;
    this.simulated.set(drone, v);
    this.refresh();
  }

  /** Show or hide the panel as role, lease, drone and mode stand now. */
  refresh() {
    const drone = this.env.drone();
    const allowed = trainingAllowed({
      role: this.env.role(),
      lease: this.env.lease(),
      simulated: drone ? this.simulated.get(drone) : undefined,
      replay: this.env.replay(),
    });
    this.root.hidden = !allowed;
    if (!allowed) this.root.open = false;
    this.root.dataset.drone = drone || "";
  }

  async inject(body, words) {
    const drone = this.env.drone();
    if (!drone) return;
    try {
      await this.api.post(`/sim/${encodeURIComponent(drone)}/fault`, body);
      const text = `Training: ${words} on ${drone}.`;
      this.status.textContent = text;
      this.status.dataset.level = "ok";
      this.env.say(text);
    } catch (err) {
      this.status.textContent = `Fault not injected: ${err.message}`;
      this.status.dataset.level = "warn";
    }
  }
}
