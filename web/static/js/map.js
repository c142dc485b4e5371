// Map panel: a top-down canvas of the world (room walls and markers, or the GPS field with
// waypoints and stations) with every drone's estimated pose, heading, trail and current target.
// Map frame per docs/CONVENTIONS.md: x east / along the room, y north / across it, metres; the
// canvas draws +y upwards.

import { flightLabel } from "./status.js";
import { quaternionYaw } from "./util.js";

const TRAIL_LEN = 400;
const HIT_PX = 16;

export class MapPanel {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{popover: HTMLElement, text: HTMLElement, go: HTMLButtonElement, cancel: HTMLButtonElement,
   *          caption: HTMLElement}} els
   * @param {(markerId: number) => void} onGo called when the operator picks "Go there"
   */
  constructor(canvas, els, onGo) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.els = els;
    this.onGo = onGo;
    this.world = null;
    this.selected = null; // drone name whose pose comes from /uav/pose
    /** name -> {x, y, yaw, role, battery, trail: [[x,y]...]} */
    this.drones = new Map();
    this.targetMarker = null;
    this.visibleMarkers = new Set();
    this.visibleAt = 0;
    this.popoverMarker = null;
    this.dirty = true;
    canvas.addEventListener("click", (ev) => this.onClick(ev));
    // Keyboard: arrows pick a marker (the popover follows), Enter/Space fly there via the
    // popover's button, Esc (handled by the page) closes it.
    this.keyIndex = -1;
    canvas.addEventListener("keydown", (ev) => this.onKey(ev));
    els.go.addEventListener("click", () => {
      if (this.popoverMarker !== null) this.onGo(this.popoverMarker);
      this.hidePopover();
    });
    els.cancel.addEventListener("click", () => this.hidePopover());
    const ro = new ResizeObserver(() => {
      this.resize();
    });
    ro.observe(canvas);
    this.resize();
    const loop = () => {
      if (this.dirty) this.draw();
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  setWorld(world) {
    this.world = world;
    const kind = world.kind || (world.gps_origin ? "outdoor" : "indoor");
    const b = world.bounds || {};
    const size = `${fmtM(b.x_max - b.x_min)} × ${fmtM(b.y_max - b.y_min)} m`;
    this.els.caption.textContent = `${world.name || kind} · ${size}`;
    this.dirty = true;
  }

  /** Forget every drone's trail (a replay jumped in time). */
  clearTrails() {
    for (const d of this.drones.values()) d.trail = [];
    this.dirty = true;
  }

  setSelected(name) {
    this.selected = name;
    this.dirty = true;
  }

  drone(name) {
    let d = this.drones.get(name);
    if (!d) {
      d = { x: null, y: null, yaw: 0, role: "", battery: null, trail: [] };
      this.drones.set(name, d);
    }
    return d;
  }

  /** geometry_msgs/PoseStamped of ``name`` (the EKF estimate). */
  onPose(name, msg, live = true) {
    const p = msg?.pose?.position;
    if (!p || !Number.isFinite(p.x) || !Number.isFinite(p.y)) return;
    const d = this.drone(name);
    if (live) d.poseAt = performance.now();
    // Before the first marker fix the estimate is a guess: keep it off the trail.
    const guess = d.localised === false;
    d.x = p.x;
    d.y = p.y;
    d.z = p.z;
    d.yaw = quaternionYaw(msg.pose.orientation);
    if (!guess) pushTrail(d, p.x, p.y);
    this.dirty = true;
  }

  /**
   * The REST snapshot's estimate (x, y, yaw_rad, localised), used only while /uav/pose is
   * silent, so the map still shows the drone when the topic is not flowing.
   */
  onSnapshot(name, st) {
    const d = this.drone(name);
    if (performance.now() - (d.poseAt || 0) < 1500) return;
    if (!st || st.localised === false || !Number.isFinite(st.x) || !Number.isFinite(st.y)) return;
    this.onPose(name, {
      pose: {
        position: { x: st.x, y: st.y, z: st.z ?? 0 },
        orientation: { x: 0, y: 0, z: Math.sin((st.yaw_rad || 0) / 2), w: Math.cos((st.yaw_rad || 0) / 2) },
      },
    }, false);
  }

  /** Whether the estimator knows where the drone is (REST ``localised``); unknown is null. */
  setLocalised(name, localised) {
    const d = this.drone(name);
    const v = typeof localised === "boolean" ? localised : null;
    if (d.localised !== v) {
      d.localised = v;
      this.dirty = true;
    }
  }

  /** The selected drone's flight state, as the status bar says it (labels agree). */
  setFlightLabel(name, label) {
    if (!name) return;
    const d = this.drone(name);
    if (d.flight !== label) {
      d.flight = label;
      d.flightLive = true;
      this.dirty = true;
    }
  }

  /** uav_console/FleetStatus: every drone with its role. */
  onFleet(msg) {
    for (const s of msg?.drones || []) {
      const d = this.drone(s.name);
      d.role = s.role || "";
      if (!(s.name === this.selected && d.flightLive)) d.flight = flightLabel(s.state);
      d.battery = s.battery;
      d.link = s.link;
      // The fleet status is coarse; the selected drone's pose topic is fresher.
      if (s.name !== this.selected && s.position && Number.isFinite(s.position.x)) {
        d.x = s.position.x;
        d.y = s.position.y;
        d.yaw = ((s.yaw_deg || 0) * Math.PI) / 180;
        pushTrail(d, d.x, d.y);
      }
    }
    this.dirty = true;
  }

  /** uav_console/MarkerArray: the markers the camera sees now (ringed on the map). */
  onMarkers(msg) {
    const ids = new Set((msg?.markers || []).map((m) => m.id));
    const same = ids.size === this.visibleMarkers.size && [...ids].every((i) => this.visibleMarkers.has(i));
    this.visibleMarkers = ids;
    this.visibleAt = performance.now();
    if (!same) this.dirty = true;
  }

  /** uav_console/TaskStatus: remember a marker target ("goto" / "marker 3") to highlight. */
  onTask(msg) {
    const text = `${msg?.name || ""} ${msg?.detail || ""}`;
    const m = /marker\D{0,3}(\d+)/i.exec(text);
    const active = !/(done|succeeded|failed|cancel|idle)/i.test(msg?.state || "");
    const next = m && active ? Number(m[1]) : null;
    if (next !== this.targetMarker) {
      this.targetMarker = next;
      this.dirty = true;
    }
  }

  resize() {
    const dpr = window.devicePixelRatio || 1;
    const rect = this.canvas.getBoundingClientRect();
    if (rect.width < 2) return;
    const w = Math.round(rect.width * dpr);
    const h = Math.round(rect.height * dpr);
    if (this.canvas.width !== w || this.canvas.height !== h) {
      this.canvas.width = w;
      this.canvas.height = h;
    }
    this.dirty = true;
  }

  /** World (metres) -> canvas CSS pixels. */
  transform() {
    const rect = this.canvas.getBoundingClientRect();
    const b = this.world?.bounds || { x_min: 0, x_max: 8, y_min: 0, y_max: 6 };
    const margin = 18;
    const sx = (rect.width - 2 * margin) / Math.max(1e-6, b.x_max - b.x_min);
    const sy = (rect.height - 2 * margin) / Math.max(1e-6, b.y_max - b.y_min);
    const s = Math.min(sx, sy);
    const ox = (rect.width - s * (b.x_max - b.x_min)) / 2;
    const oy = (rect.height - s * (b.y_max - b.y_min)) / 2;
    return {
      s,
      px: (x) => ox + (x - b.x_min) * s,
      py: (y) => rect.height - (oy + (y - b.y_min) * s),
    };
  }

  draw() {
    this.dirty = false;
    const ctx = this.ctx;
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    const rect = this.canvas.getBoundingClientRect();
    ctx.clearRect(0, 0, rect.width, rect.height);
    const css = getComputedStyle(document.documentElement);
    const col = (name) => css.getPropertyValue(name).trim();
    if (!this.world) {
      ctx.fillStyle = col("--muted");
      ctx.font = "14px system-ui";
      ctx.fillText("Loading the world…", 12, 24);
      return;
    }
    const T = this.transform();
    const b = this.world.bounds;
    const outdoor = (this.world.kind || "") === "outdoor" || !!this.world.gps_origin;

    // grid: 1 m indoors, 10 m outdoors
    const step = outdoor ? 10 : 1;
    ctx.strokeStyle = col("--map-grid");
    ctx.lineWidth = 1;
    ctx.beginPath();
    for (let x = Math.ceil(b.x_min / step) * step; x <= b.x_max; x += step) {
      ctx.moveTo(T.px(x), T.py(b.y_min));
      ctx.lineTo(T.px(x), T.py(b.y_max));
    }
    for (let y = Math.ceil(b.y_min / step) * step; y <= b.y_max; y += step) {
      ctx.moveTo(T.px(b.x_min), T.py(y));
      ctx.lineTo(T.px(b.x_max), T.py(y));
    }
    ctx.stroke();

    // walls (indoor) or field boundary (outdoor)
    ctx.strokeStyle = col("--map-wall");
    ctx.lineWidth = outdoor ? 1 : 3;
    ctx.setLineDash(outdoor ? [6, 4] : []);
    ctx.strokeRect(T.px(b.x_min), T.py(b.y_max), (b.x_max - b.x_min) * T.s, (b.y_max - b.y_min) * T.s);
    ctx.setLineDash([]);

    // furniture and other objects, faintly
    ctx.fillStyle = col("--map-grid");
    for (const o of this.world.objects || []) {
      const w = o.size?.w ?? 0.3;
      const d = o.size?.d ?? 0.3;
      if (!o.position) continue;
      ctx.save();
      ctx.translate(T.px(o.position.x), T.py(o.position.y));
      ctx.rotate(-((o.yaw_deg || 0) * Math.PI) / 180);
      ctx.fillRect((-w / 2) * T.s, (-d / 2) * T.s, Math.max(2, w * T.s), Math.max(2, d * T.s));
      ctx.restore();
    }

    // waypoints (outdoor patrol route)
    const wps = this.world.waypoints || [];
    if (wps.length) {
      ctx.strokeStyle = col("--accent");
      ctx.lineWidth = 1.5;
      ctx.setLineDash([4, 3]);
      ctx.beginPath();
      wps.forEach((w, i) => {
        const f = i ? ctx.lineTo.bind(ctx) : ctx.moveTo.bind(ctx);
        f(T.px(w.position.x), T.py(w.position.y));
      });
      ctx.closePath();
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = col("--accent");
      ctx.font = "11px system-ui";
      for (const w of wps) {
        const x = T.px(w.position.x);
        const y = T.py(w.position.y);
        ctx.beginPath();
        ctx.moveTo(x, y - 6);
        ctx.lineTo(x + 6, y);
        ctx.lineTo(x, y + 6);
        ctx.lineTo(x - 6, y);
        ctx.closePath();
        ctx.fill();
        ctx.fillText(String(w.id), x + 8, y - 6);
      }
    }

    // stations (home pads)
    ctx.strokeStyle = col("--ok");
    ctx.fillStyle = col("--ok");
    ctx.font = "10px system-ui";
    ctx.lineWidth = 1.5;
    for (const s of this.world.stations || []) {
      const x = T.px(s.position.x);
      const y = T.py(s.position.y);
      ctx.beginPath();
      ctx.arc(x, y, 7, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.fillText("H", x - 3, y + 3.5);
    }

    // markers: a square on the wall with a tick along the direction it faces, and its id
    ctx.font = "bold 11px system-ui";
    for (const m of this.world.markers || []) {
      const x = T.px(m.position.x);
      const y = T.py(m.position.y);
      const yaw = m.yaw_rad ?? ((m.yaw_deg || 0) * Math.PI) / 180;
      const target = m.id === this.targetMarker;
      const picked = m.id === this.popoverMarker;
      const seen = this.visibleMarkers.has(m.id) && performance.now() - this.visibleAt < 1000;
      if (seen) {
        ctx.fillStyle = col("--ok");
        ctx.globalAlpha = 0.35;
        ctx.beginPath();
        ctx.arc(x, y, 9, 0, 2 * Math.PI);
        ctx.fill();
        ctx.globalAlpha = 1;
      }
      ctx.fillStyle = target ? col("--warn") : col("--text");
      ctx.fillRect(x - 5, y - 5, 10, 10);
      ctx.strokeStyle = ctx.fillStyle;
      ctx.lineWidth = 2;
      ctx.beginPath();
      ctx.moveTo(x, y);
      ctx.lineTo(x + Math.cos(yaw) * 12, y - Math.sin(yaw) * 12);
      ctx.stroke();
      if (target || picked) {
        ctx.beginPath();
        ctx.arc(x, y, 11, 0, 2 * Math.PI);
        ctx.stroke();
      }
      const lx = x + Math.cos(yaw) * 20 - 4;
      const ly = y - Math.sin(yaw) * 20 + 4;
      ctx.fillText(String(m.id), lx, ly);
    }

    // drones: trail, body, heading
    for (const [name, d] of this.drones) {
      if (d.x === null) continue;
      const mine = name === this.selected;
      const colour = mine ? col("--accent") : col("--muted");
      const lost = d.localised === false;
      ctx.strokeStyle = colour;
      ctx.globalAlpha = 0.55;
      ctx.lineWidth = 2;
      ctx.beginPath();
      let pen = false;
      for (const pt of d.trail) {
        if (pt === null) {
          pen = false; // a jump (re-localisation): the trail breaks here
          continue;
        }
        if (pen) ctx.lineTo(T.px(pt[0]), T.py(pt[1]));
        else ctx.moveTo(T.px(pt[0]), T.py(pt[1]));
        pen = true;
      }
      ctx.stroke();
      ctx.globalAlpha = 1;
      const x = T.px(d.x);
      const y = T.py(d.y);
      ctx.save();
      ctx.translate(x, y);
      ctx.rotate(-d.yaw);
      ctx.globalAlpha = lost ? 0.35 : 1;
      ctx.fillStyle = colour;
      ctx.beginPath();
      ctx.moveTo(12, 0);
      ctx.lineTo(-7, 7);
      ctx.lineTo(-3, 0);
      ctx.lineTo(-7, -7);
      ctx.closePath();
      ctx.fill();
      ctx.restore();
      ctx.fillStyle = colour;
      ctx.font = "11px system-ui";
      // The flight state (same words as the status bar), and the patrol role only while it
      // means something: "idle" in flight or "lost" after a stop would contradict the bar.
      let label = d.flight ? `${name} · ${d.flight}` : name;
      if (["patrolling", "relieving", "returning"].includes(d.role)) label += ` · ${d.role}`;
      if (lost) label += " · not localised";
      ctx.fillText(label, x + 10, y + 16);
    }
    this.canvas.dataset.drawn = String((Number(this.canvas.dataset.drawn) || 0) + 1);
  }

  onClick(ev) {
    if (!this.world) return;
    const rect = this.canvas.getBoundingClientRect();
    const cx = ev.clientX - rect.left;
    const cy = ev.clientY - rect.top;
    const T = this.transform();
    let best = null;
    let bestD = HIT_PX;
    for (const m of this.world.markers || []) {
      const d = Math.hypot(T.px(m.position.x) - cx, T.py(m.position.y) - cy);
      if (d <= bestD) {
        best = m;
        bestD = d;
      }
    }
    if (!best) {
      this.hidePopover();
      return;
    }
    this.showPopover(best.id, cx, cy);
  }

  /** Offer "go there" for a marker (also used by tests and keyboard users via the console). */
  showPopover(id, cx, cy) {
    this.popoverMarker = id;
    const pop = this.els.popover;
    this.els.text.textContent = `Marker ${id}`;
    this.els.go.textContent = `Go to marker ${id}`;
    pop.hidden = false;
    const rect = this.canvas.getBoundingClientRect();
    pop.style.left = `${Math.min(Math.max(4, cx + 8), rect.width - pop.offsetWidth - 4)}px`;
    pop.style.top = `${Math.min(Math.max(4, cy + 8), rect.height - pop.offsetHeight - 4)}px`;
    this.els.go.focus();
    this.dirty = true;
  }

  onKey(ev) {
    const markers = [...(this.world?.markers || [])].sort((a, b) => a.id - b.id);
    if (!markers.length) return;
    if (["ArrowRight", "ArrowDown", "ArrowLeft", "ArrowUp", "Home", "End"].includes(ev.key)) {
      ev.preventDefault();
      ev.stopPropagation(); // arrows here pick markers; they never jog the drone
      const n = markers.length;
      if (ev.key === "Home") this.keyIndex = 0;
      else if (ev.key === "End") this.keyIndex = n - 1;
      else {
        const step = ev.key === "ArrowRight" || ev.key === "ArrowDown" ? 1 : -1;
        this.keyIndex = this.keyIndex < 0 ? (step > 0 ? 0 : n - 1) : (this.keyIndex + step + n) % n;
      }
      const m = markers[this.keyIndex];
      this.popoverMarker = m.id;
      this.els.focus && (this.els.focus.textContent = `Marker ${m.id} of ${n}. Enter offers to fly there.`);
      this.dirty = true;
    } else if ((ev.key === "Enter" || ev.key === " ") && this.popoverMarker !== null) {
      ev.preventDefault();
      ev.stopPropagation();
      const p = this.markerPixel(this.popoverMarker);
      if (p) this.showPopover(this.popoverMarker, p.x, p.y);
    }
  }

  hidePopover() {
    this.popoverMarker = null;
    this.els.popover.hidden = true;
    this.dirty = true;
  }

  /** Canvas CSS-pixel position of marker ``id`` (for tests and the accessibility summary). */
  markerPixel(id) {
    const m = (this.world?.markers || []).find((k) => k.id === id);
    if (!m) return null;
    const T = this.transform();
    return { x: T.px(m.position.x), y: T.py(m.position.y) };
  }
}

// A step longer than this between two estimates is a re-localisation, not a flight: break the line.
const TRAIL_JUMP_M = 1.0;

function pushTrail(d, x, y) {
  let last = null;
  for (let i = d.trail.length - 1; i >= 0 && last === null; i -= 1) last = d.trail[i];
  if (last && Math.hypot(last[0] - x, last[1] - y) <= 0.03) return;
  if (last && Math.hypot(last[0] - x, last[1] - y) > TRAIL_JUMP_M) d.trail.push(null);
  d.trail.push([x, y]);
  while (d.trail.length > TRAIL_LEN) d.trail.shift();
}

function fmtM(v) {
  return Number.isFinite(v) ? String(Math.round(v * 10) / 10) : "?";
}
