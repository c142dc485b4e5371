// Telemetry panel: battery gauge, altitude, speed, heading, control state, link quality, control
// loop health and the running task, with warnings in colour.
//
// Sources: /ardrone/navdata (ardrone_autonomy/Navdata: batteryPercent %, altd mm, vx/vy mm/s,
// rotZ deg, state, pressure Pa, temp 0.1 °C), /uav/task (uav_console/TaskStatus), and GET /api/v1/drones/{id} for the
// server's view of the link and the 100 Hz controller's timing.

import { flightLabel, flightLevel } from "./status.js";
import { fmt, setLevel, setText, wrap360 } from "./util.js";

// DESIGN §5 / server Settings defaults: battery_low_pct 25, battery_critical_pct 12,
// link_timeout_s 0.5; demo navdata arrives at ~15 Hz (AR.Drone SDK 2.0 §7.1).
export const BATTERY_LOW_PCT = 25;
export const BATTERY_CRITICAL_PCT = 12;
export const LINK_TIMEOUT_S = 0.5;
export const NAVDATA_OK_HZ = 10;
// The controller runs at 100 Hz (10 ms period): a p99 period error above half a period is worth a
// warning, above two periods the control is degraded (alert), as is a rate below 50 Hz.
export const LOOP_WARN_MS = 5;
export const LOOP_ALERT_MS = 20;

export class TelemetryPanel {
  constructor(root, now = () => performance.now() / 1000) {
    this.$ = (id) => root.querySelector(`#${id}`);
    this.now = now;
    this.navTimes = [];
    this.lastNav = null;
    this.serverLink = null;
    this.emergency = false;
    this.poseAt = null; // when the map-frame heading last came from /uav/pose
    /** Called with (label, battery %) whenever they change: the status bar follows. */
    this.onFlight = () => {};
    /** Called with (text, level, lost) on every link render. */
    this.onLink = () => {};
    /** Called on every navdata message: a word from the vehicle (freshness.js). */
    this.onNavdataSeen = () => {};
    this.timer = setInterval(() => this.renderLink(), 250);
    this.renderLink();
  }

  onNavdata(msg) {
    const t = this.now();
    this.navTimes.push(t);
    while (this.navTimes.length && t - this.navTimes[0] > 2) this.navTimes.shift();
    this.lastNav = t;
    this.onNavdataSeen();

    const battery = Number(msg.batteryPercent);
    const meter = this.$("battery-meter");
    if (Number.isFinite(battery)) {
      meter.value = battery;
      setText(this.$("battery"), `${Math.round(battery)} %`);
      const level =
        battery <= BATTERY_CRITICAL_PCT ? "alert" : battery <= BATTERY_LOW_PCT ? "warn" : "ok";
      setLevel(this.$("m-battery"), level);
    }
    const altM = Number(msg.altd) / 1000;
    setText(this.$("altitude"), `${fmt(altM, 2)} m`);
    const speed = Math.hypot(Number(msg.vx) || 0, Number(msg.vy) || 0) / 1000;
    setText(this.$("speed"), `${fmt(speed, 2)} m/s`);
    // rotZ is REP 103 yaw in degrees (counter-clockwise positive) in the drone's own frame;
    // the EKF's map-frame heading (/uav/pose) is preferred when it flows.
    const yaw = Number(msg.rotZ);
    if (Number.isFinite(yaw) && (this.poseAt === null || t - this.poseAt > 1.5)) {
      this.showHeading(compassBearing(yaw));
    }
    // Barometer (navdata option 21, as ardrone_autonomy fills them): pressure in Pa, temp in
    // 0.1 °C; 0 when the drone sends no barometer option.
    const pa = Number(msg.pressure);
    const baro = Number.isFinite(pa) && pa > 0;
    setText(this.$("pressure"), baro ? `${fmt(pa / 100, 1)} hPa` : "–");
    setText(this.$("temperature"), baro ? `${fmt(Number(msg.temp) / 10, 1)} °C` : "–");
    const state = Number(msg.state);
    this.showFlight(flightLabel(state, { emergency: this.emergency }));
    this.$("ctrl-state").dataset.state = String(state);
    this.onFlight(this.flight, Number.isFinite(battery) ? battery : null);
  }

  /** Map-frame yaw (rad, REP 103) from /uav/pose: the heading as a compass bearing. */
  onPoseYaw(yawRad) {
    if (!Number.isFinite(yawRad)) return;
    this.poseAt = this.now();
    this.showHeading(compassBearing((yawRad * 180) / Math.PI));
  }

  showHeading(bearing) {
    setText(this.$("heading"), Number.isFinite(bearing) ? `${bearing}°` : "–");
    this.$("heading").title = "Compass bearing: 0° = north (map +y), 90° = east (map +x)";
  }

  showFlight(label) {
    this.flight = label;
    setText(this.$("ctrl-state"), label);
    setLevel(this.$("m-state"), flightLevel(label));
  }

  onTask(msg) {
    const parts = [msg.name, msg.state].filter(Boolean);
    let text = parts.join(" · ") || "–";
    if (Number.isFinite(msg.progress) && msg.progress > 0 && msg.progress < 1) {
      text += ` · ${Math.round(msg.progress * 100)} %`;
    }
    if (msg.detail) text += ` — ${msg.detail}`;
    setText(this.$("task"), text);
    this.$("task").title = text;
    const failed = /fail|abort|refus/i.test(msg.state || "");
    setLevel(this.$("m-task"), failed ? "warn" : "ok");
  }

  /** Fold in GET /api/v1/drones/{id}: link flag and controller timing, where present. */
  onDroneStatus(status) {
    if (!status || typeof status !== "object") return;
    this.serverLink = linkFlag(status);
    // The emergency flag (navdata state bit 31) is not in ardrone_autonomy's Navdata message.
    this.emergency = status.emergency === true;
    if (this.emergency && this.flight !== "Emergency") {
      this.showFlight("Emergency");
      this.onFlight(this.flight, num(status.battery_pct));
    }
    document.body.dataset.droneEmergency = this.emergency ? "1" : "";
    // Navdata over rosbridge is the live source; the 1 Hz REST snapshot fills in without it,
    // but never with a snapshot older than what is shown (a vehicle process gone silent, a lost
    // link: the server answers with its last word, the panel keeps the newer one, greyed).
    const silent = this.lastNav === null || this.now() - this.lastNav > 1.5;
    const fresh = status.link_ok !== false && status.vehicle?.connected !== false;
    if (silent && fresh) this.fromSnapshot(status);
    const loop = loopHealth(status);
    const el = this.$("loop");
    if (!loop) {
      setText(el, "–");
      setLevel(this.$("m-loop"), "unknown");
      return;
    }
    const bits = [];
    if (loop.rate_hz !== null) bits.push(`${Math.round(loop.rate_hz)} Hz`);
    if (loop.p99_ms !== null) bits.push(`p99 ${fmt(loop.p99_ms, 2)} ms`);
    if (loop.overruns) bits.push(`${loop.overruns} late`);
    if (loop.stalls) bits.push(`${loop.stalls} stalls`);
    if (loop.stalled) bits.push("stalled");
    setText(el, bits.join(" · ") || "running");
    el.title = el.textContent;
    const level =
      loop.stalled || (loop.p99_ms ?? 0) > LOOP_ALERT_MS
        ? "alert"
        : (loop.p99_ms ?? 0) > LOOP_WARN_MS || loop.stalls > 0
          ? "warn"
          : "ok";
    setLevel(this.$("m-loop"), level);
  }

  /** Battery, altitude, speed, heading and state from a REST snapshot (VehicleSnapshot fields). */
  fromSnapshot(st) {
    const battery = num(st.battery_pct);
    if (battery !== null) {
      this.$("battery-meter").value = battery;
      setText(this.$("battery"), `${Math.round(battery)} %`);
      const level =
        battery <= BATTERY_CRITICAL_PCT ? "alert" : battery <= BATTERY_LOW_PCT ? "warn" : "ok";
      setLevel(this.$("m-battery"), level);
    }
    const alt = num(st.altitude_m) ?? num(st.z);
    if (alt !== null) setText(this.$("altitude"), `${fmt(alt, 2)} m`);
    const vx = num(st.vx);
    const vy = num(st.vy);
    if (vx !== null && vy !== null) setText(this.$("speed"), `${fmt(Math.hypot(vx, vy), 2)} m/s`);
    const yaw = num(st.yaw_rad);
    if (yaw !== null) this.showHeading(compassBearing((yaw * 180) / Math.PI));
    if (typeof st.ctrl_state === "string" && st.ctrl_state) {
      this.showFlight(flightLabel(st.ctrl_state, { emergency: st.emergency === true }));
      this.onFlight(this.flight, battery);
    }
  }

  renderLink() {
    const el = this.$("link");
    if (this.lastNav === null) {
      setText(el, this.serverLink === false ? "lost" : "waiting");
      setLevel(this.$("m-link"), this.serverLink === false ? "alert" : "unknown");
      this.onLink(el.textContent, this.$("m-link").dataset.level, this.serverLink === false);
      return;
    }
    const age = this.now() - this.lastNav;
    const t = this.now();
    const recent = this.navTimes.filter((x) => t - x <= 2);
    // Rate from the intervals between packets (right from the first two, not a window count).
    const rate =
      recent.length < 2 ? 0 : (recent.length - 1) / Math.max(1e-3, recent[recent.length - 1] - recent[0]);
    const lost = age > LINK_TIMEOUT_S || this.serverLink === false;
    if (lost) {
      setText(el, `lost (${fmt(age, 1)} s)`);
      setLevel(this.$("m-link"), "alert");
    } else {
      setText(el, `${Math.round(rate)} Hz`);
      setLevel(this.$("m-link"), rate >= NAVDATA_OK_HZ ? "ok" : "warn");
    }
    this.onLink(el.textContent, this.$("m-link").dataset.level, lost);
  }
}

/** Compass bearing 0–359° (0 = north = map +y, clockwise) of a REP 103 yaw in degrees. */
export function compassBearing(yawDeg) {
  return Math.round(wrap360(90 - yawDeg)) % 360;
}

function num(v) {
  return typeof v === "number" && Number.isFinite(v) ? v : null;
}

/** The server's link flag from a drone status (``link`` bool, or ``link.ok``/``link_ok``). */
export function linkFlag(status) {
  if (typeof status.link === "boolean") return status.link;
  if (status.link && typeof status.link.ok === "boolean") return status.link.ok;
  if (typeof status.link_ok === "boolean") return status.link_ok;
  const tel = status.telemetry;
  if (tel && typeof tel.link_ok === "boolean") return tel.link_ok;
  return null;
}

/**
 * Controller timing from a drone status, tolerant of where the server puts it
 * (``control``, ``controller``, ``loop`` or ``control_loop``, at top level or under telemetry).
 */
export function loopHealth(status) {
  const holders = [status, status.telemetry || {}];
  let c = null;
  for (const h of holders) {
    for (const key of ["control_loop", "controller", "control", "loop"]) {
      if (h[key] && typeof h[key] === "object") {
        c = h[key];
        break;
      }
    }
    if (c) break;
  }
  if (!c) return null;
  const period = num(c.period_ms) ?? (num(c.period_s) !== null ? c.period_s * 1000 : null);
  const rate = num(c.rate_hz) ?? (period ? 1000 / period : null);
  let p99 = num(c.jitter_p99_ms) ?? num(c.p99_ms);
  for (const key of ["period_error_p99_s", "jitter_p99_s", "lateness_p99_s"]) {
    if (p99 === null && num(c[key]) !== null) p99 = c[key] * 1000;
  }
  if (p99 === null && c.jitter && typeof c.jitter === "object") {
    p99 = num(c.jitter.p99_ms) ?? (num(c.jitter.p99_s) !== null ? c.jitter.p99_s * 1000 : null);
  }
  const overruns = num(c.overruns);
  // ``stalls`` counts watchdog trips since start (history); a rate far below 100 Hz is now.
  const stalls = num(c.stalls) ?? 0;
  const stalled = c.stalled === true || (rate !== null && rate < 50);
  return { rate_hz: rate, p99_ms: p99, overruns, stalls, stalled };
}
