// Direct control and emergency override: take off, land, hover, reset, EMERGENCY STOP, a jog pad
// publishing geometry_msgs/Twist on /cmd_vel at ~10 Hz while held (a zero Twist on release),
// and keyboard shortcuts. Independent of the dialog: these never wait for it.
//
// /cmd_vel semantics as ardrone_autonomy: components are fractions in [-1, 1]; linear.x forward,
// linear.y left, linear.z up, angular.z counter-clockwise (docs/CONVENTIONS.md, protocols.md).

export const JOG_PERIOD_MS = 100; // ~10 Hz, well inside the drone's 2 s command watchdog
const SAID_MS = 4000; // how long a button says why it did nothing

export const JOG_AXES = Object.freeze({
  forward: ["linear", "x", 1],
  backward: ["linear", "x", -1],
  left: ["linear", "y", 1],
  right: ["linear", "y", -1],
  up: ["linear", "z", 1],
  down: ["linear", "z", -1],
  yaw_left: ["angular", "z", 1],
  yaw_right: ["angular", "z", -1],
});

export const KEYMAP = Object.freeze({
  w: "forward",
  arrowup: "forward",
  s: "backward",
  arrowdown: "backward",
  a: "left",
  arrowleft: "left",
  d: "right",
  arrowright: "right",
  r: "up",
  pageup: "up",
  f: "down",
  pagedown: "down",
  q: "yaw_left",
  e: "yaw_right",
});

// Keys that move the drone: they work only while keyboard flying is armed (a letter typed
// outside the command box must never launch the drone). Stops (Shift+Esc, Space = hover,
// L = land) always work.
export const MOVING_KEYS = Object.freeze(new Set(["t", ...Object.keys(KEYMAP)]));

/** What a keydown means: "emergency" (Shift+Esc), "close" (Esc) or null. */
export function escapeMeaning(ev) {
  if (ev.key !== "Escape") return null;
  return ev.shiftKey ? "emergency" : "close";
}

export function zeroTwist() {
  return { linear: { x: 0, y: 0, z: 0 }, angular: { x: 0, y: 0, z: 0 } };
}

/** The Twist for a set of held directions at strength ``s`` (opposites cancel). */
export function twistFor(held, s) {
  const t = zeroTwist();
  for (const dir of held) {
    const axis = JOG_AXES[dir];
    if (!axis) continue;
    const [part, comp, sign] = axis;
    t[part][comp] = Math.max(-1, Math.min(1, t[part][comp] + sign * s));
  }
  return t;
}

export class Controls {
  /**
   * @param {HTMLElement} root
   * @param {{action: (name: string, source?: string) => void, twist: (t: object) => void,
   *          focusInput: () => void, mic: () => void, describe?: () => void,
   *          close?: () => boolean, disarmedKey?: (key: string) => void}} hooks
   */
  constructor(root, hooks) {
    this.root = root;
    this.hooks = hooks;
    this.held = new Set();
    this.pointerHeld = new Map(); // pointerId -> direction
    this.keyHeld = new Map(); // key -> direction
    this.timer = null;
    this.enabled = true;
    this.stopsEnabled = true; // Land and Hover (Space, L): any pilot, lease or not
    this.armed = false; // keyboard flying: off at every page load
    this.saidTimers = new Map(); // button id -> timer of what it says (say)
    this.armButton = root.querySelector("#arm-keys");
    this.armButton?.addEventListener("click", () => this.setArmed(!this.armed));
    this.speedInput = root.querySelector("#jog-speed");
    this.speedOut = root.querySelector("#jog-speed-out");
    this.speedInput.addEventListener("input", () => this.renderSpeed());
    this.renderSpeed();
    this.setArmed(false);

    const bind = (id, action, stop = false) =>
      root.querySelector(id).addEventListener("click", () => {
        if (this.enabled || (stop && this.stopsEnabled)) hooks.action(action, "button");
      });
    bind("#btn-takeoff", "takeoff");
    bind("#btn-land", "land", true);
    bind("#btn-hover", "hover", true);
    bind("#btn-reset", "reset");
    // Emergency on pointerdown as well as click: it must not wait for the finger to lift.
    const em = root.querySelector("#btn-emergency");
    let emAt = 0;
    const fire = () => {
      const now = performance.now();
      if (now - emAt < 300) return; // pointerdown + click of one press
      emAt = now;
      this.releaseAll(false);
      hooks.action("emergency", "button");
    };
    em.addEventListener("pointerdown", (ev) => {
      if (ev.button === 0) fire();
    });
    em.addEventListener("click", fire);

    for (const btn of root.querySelectorAll("[data-jog]")) {
      const dir = btn.dataset.jog;
      btn.addEventListener("pointerdown", (ev) => {
        if (!this.enabled || btn.disabled) return;
        ev.preventDefault();
        btn.setPointerCapture?.(ev.pointerId);
        this.pointerHeld.set(ev.pointerId, dir);
        btn.classList.add("active");
        this.update();
      });
      const up = (ev) => {
        if (!this.pointerHeld.has(ev.pointerId)) return;
        this.pointerHeld.delete(ev.pointerId);
        btn.classList.remove("active");
        this.update();
      };
      btn.addEventListener("pointerup", up);
      btn.addEventListener("pointercancel", up);
      btn.addEventListener("lostpointercapture", up);
      // Keyboard users: Enter/Space on a focused jog button jogs while the key is down.
      btn.addEventListener("keydown", (ev) => {
        if ((ev.key === "Enter" || ev.key === " ") && !ev.repeat && this.enabled) {
          ev.preventDefault();
          ev.stopPropagation();
          this.keyHeld.set(`btn:${ev.key}`, dir);
          btn.classList.add("active");
          this.update();
        }
      });
      btn.addEventListener("keyup", (ev) => {
        if (this.keyHeld.delete(`btn:${ev.key}`)) {
          ev.stopPropagation();
          btn.classList.remove("active");
          this.update();
        }
      });
      btn.addEventListener("contextmenu", (ev) => ev.preventDefault());
    }

    document.addEventListener("keydown", (ev) => this.onKeyDown(ev));
    document.addEventListener("keyup", (ev) => this.onKeyUp(ev));
    // Losing the page while jogging must stop the drone (DESIGN §5, operator gone -> hover).
    window.addEventListener("blur", () => this.releaseAll(true));
    document.addEventListener("visibilitychange", () => {
      if (document.hidden) this.releaseAll(true);
    });
  }

  /** Say ``text`` on button ``id`` for a few seconds (console.css shows data-said under it). */
  say(id, text, ms = SAID_MS) {
    const btn = this.root.querySelector(`#${id}`);
    if (!btn) return;
    btn.dataset.said = text;
    btn.setAttribute("aria-description", text);
    clearTimeout(this.saidTimers.get(id));
    this.saidTimers.set(
      id,
      setTimeout(() => {
        delete btn.dataset.said;
        btn.removeAttribute("aria-description");
      }, ms),
    );
  }

  strength() {
    return Number(this.speedInput.value) || 0.3;
  }

  renderSpeed() {
    this.speedOut.textContent = `${Math.round(this.strength() * 100)} %`;
  }

  /** ``on``: every control; ``stops``: Land and Hover (a pilot without the lease keeps them). */
  setEnabled(on, stops = on) {
    this.enabled = on;
    this.stopsEnabled = stops;
    if (!on) this.releaseAll(false);
  }

  /** Arm or disarm the keys that move the drone (disarming also stops a keyboard jog). */
  setArmed(on) {
    this.armed = !!on;
    if (!this.armed) {
      for (const [k] of this.keyHeld) if (!k.startsWith("btn:")) this.keyHeld.delete(k);
      this.update();
    }
    if (this.armButton) {
      this.armButton.setAttribute("aria-pressed", String(this.armed));
      this.armButton.textContent = this.armed ? "Keyboard flying: ON (T, WASD…)" : "Keyboard flying: off";
    }
    this.root.dataset.keysArmed = String(this.armed);
  }

  onKeyDown(ev) {
    const escape = escapeMeaning(ev);
    if (escape === "emergency") {
      // Shift+Esc: a deliberate chord, never a reflex; works everywhere, even while typing.
      ev.preventDefault();
      this.releaseAll(false);
      this.hooks.action("emergency", "keyboard");
      return;
    }
    if (escape === "close") {
      // Esc only closes what is open (a popover, a banner, the shortcuts list).
      if (this.hooks.close?.()) ev.preventDefault();
      return;
    }
    if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
    const key = ev.key.toLowerCase();
    const t = ev.target;
    const typing =
      t instanceof HTMLInputElement && t.type !== "range"
        ? true
        : t instanceof HTMLTextAreaElement || t instanceof HTMLSelectElement || t?.isContentEditable;
    const stopKey = key === " " || key === "spacebar" || (key === "l" && !ev.repeat);
    if (typing || !(this.enabled || (this.stopsEnabled && stopKey))) return;
    if (key === " " || key === "spacebar") {
      if (t instanceof HTMLButtonElement || t instanceof HTMLElement && t.tagName === "SUMMARY") return;
      ev.preventDefault();
      if (!ev.repeat) this.hooks.action("hover", "keyboard");
      return;
    }
    if (key === "/") {
      ev.preventDefault();
      this.hooks.focusInput();
      return;
    }
    if (key === "m" && !ev.repeat) {
      this.hooks.mic();
      return;
    }
    if (key === "v" && !ev.repeat) {
      this.hooks.describe?.();
      return;
    }
    if (MOVING_KEYS.has(key) && !this.armed) {
      if (!ev.repeat) this.hooks.disarmedKey?.(key);
      return;
    }
    if (key === "t" && !ev.repeat) {
      this.hooks.action("takeoff", "keyboard");
      return;
    }
    if (key === "l" && !ev.repeat) {
      this.hooks.action("land", "keyboard");
      return;
    }
    const dir = KEYMAP[key];
    if (dir) {
      ev.preventDefault();
      if (!this.keyHeld.has(key)) {
        this.keyHeld.set(key, dir);
        this.update();
      }
    }
  }

  onKeyUp(ev) {
    const key = ev.key.toLowerCase();
    if (this.keyHeld.delete(key)) this.update();
  }

  /** Recompute the held set; start/stop the 10 Hz stream; a zero Twist on release. */
  update() {
    const next = new Set([...this.pointerHeld.values(), ...this.keyHeld.values()]);
    const was = this.held.size > 0;
    this.held = next;
    this.root.dataset.jogging = next.size ? [...next].join(" ") : "";
    if (next.size) {
      this.send();
      if (!this.timer) this.timer = setInterval(() => this.send(), JOG_PERIOD_MS);
    } else {
      clearInterval(this.timer);
      this.timer = null;
      if (was) this.hooks.twist(zeroTwist());
    }
  }

  send() {
    if (this.held.size) this.hooks.twist(twistFor(this.held, this.strength()));
  }

  /** Forget every held direction; ``sendZero`` publishes the stopping Twist. */
  releaseAll(sendZero) {
    const was = this.held.size > 0;
    this.pointerHeld.clear();
    this.keyHeld.clear();
    for (const b of this.root.querySelectorAll("[data-jog].active")) b.classList.remove("active");
    this.held = new Set();
    this.root.dataset.jogging = "";
    clearInterval(this.timer);
    this.timer = null;
    if (was && sendZero) this.hooks.twist(zeroTwist());
  }
}
