// Land, Hover and Emergency down both roads at once: the web server (REST) and the vehicle's
// safety door (door.js), with one id and the time it was issued on the server's clock. The
// vehicle runs each id once, whichever road brings it first; the first acknowledgement wins.
//
// The page never says "failed" while a road may still deliver: a stop stays "pending" and
// each road keeps trying (REST again every second with the same id; the door on every
// reconnect) until one acknowledges. A newer operator command (take off, a typed command, a
// jog) supersedes a pending stop: "supersede" goes to the door, the REST request is aborted,
// and the stop is dropped: nothing fires from the past. A stop the vehicle had already run
// when its supersede arrived (the server road brought it while the door was stalled) is said
// as run, never as dropped: the door answers "too_late", or acknowledges a resent stop, and the
// supersede is sent again each time the door reopens until the door has answered it.
//
// StopSender is driven by what it is given (the REST call, the doors, the clocks), so the
// browser tests drive it with stand-ins; stopText says where a stop stands, in words.

export const STOP_ACTIONS = Object.freeze(["emergency", "land", "hover"]);
export const REST_RETRY_MS = 1000;
// Superseded stops remembered until their door answers the supersede (a page drops a few a
// minute); one pushed out is only no longer corrected if the vehicle had run it.
export const DROPPED_KEPT = 32;

/** A stop id (the same on both roads): random, 1-64 of [A-Za-z0-9_.:-]. */
export function newStopId(cryptoImpl = globalThis.crypto) {
  if (cryptoImpl?.randomUUID) return cryptoImpl.randomUUID(); // secure contexts only
  const bytes = new Uint8Array(16);
  cryptoImpl.getRandomValues(bytes);
  return Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
}

const LABELS = Object.freeze({ emergency: "Emergency stop", land: "Land", hover: "Hover" });
const ROAD_WORDS = Object.freeze({ door: "the safety door", server: "the server" });

function clock(unixS, offsetS) {
  return new Date((unixS - offsetS) * 1000).toLocaleTimeString([], { hour12: false });
}

/**
 * Where ``stop`` stands, in words, and how loud: {text, level}.
 * @param {object} stop a StopSender stop
 * @param {number} offsetS server clock - this page's clock (s), to show the server's times
 */
export function stopText(stop, offsetS = 0) {
  const label = LABELS[stop.action] || stop.action;
  const who = stop.fleet ? `${stop.drone}: ` : "";
  if (stop.state === "pending") {
    const n = stop.tryingRoads();
    const roads = `${n} road${n === 1 ? "" : "s"}`;
    return { text: `${who}${label}: stop pending, retrying on ${roads}`, level: "alert" };
  }
  if (stop.state === "delivered") {
    const ack = stop.ack;
    const at = ack.delivered !== null && ack.delivered !== undefined ? ack.delivered : null;
    const late = Number.isFinite(ack.late_s) ? ack.late_s : at !== null ? Math.max(0, at - stop.issued) : null;
    const after = late !== null ? ` after ${late.toFixed(1)} s` : "";
    const road = ROAD_WORDS[ack.road] || ack.road;
    const when = at !== null ? clock(at, offsetS) : "?";
    const verb = stop.action === "emergency" ? "stopped" : `${label.toLowerCase()} delivered`;
    return {
      text: `${who}${label}: ${verb} at ${when} (delivered${after}, by ${road})`,
      level: late !== null && late > 1 ? "warn" : "info",
    };
  }
  if (stop.state === "superseded") {
    return {
      text: `${who}${label}: the pending stop was dropped (a newer command superseded it)`,
      level: "warn",
    };
  }
  if (stop.state === "ran") {
    // superseded on the page, but the vehicle had already run it: it was not dropped
    const ack = stop.ack || {};
    const at = Number.isFinite(ack.delivered) ? ` at ${clock(ack.delivered, offsetS)}` : "";
    const road = ROAD_WORDS[ack.road] ? `, by ${ROAD_WORDS[ack.road]}` : "";
    const late = Number.isFinite(ack.late_s) ? ` ${ack.late_s.toFixed(1)} s after it was issued` : "";
    return {
      text: `${who}${label}: not dropped, it had already reached the drone${at}${late}${road}`,
      level: "alert",
    };
  }
  if (stop.state === "refused") {
    return { text: `${who}${label} not carried out: ${stop.ack?.detail || "refused"}`, level: "alert" };
  }
  // "unsent": no road can carry it (none was open, and the server refused it)
  return { text: `${who}${label} could not be sent: ${stop.why || "no road to the drone"}`, level: "alert" };
}

/**
 * Sends stops down both roads; emits "change" {detail: stop} at every step of a stop.
 *
 * @param {{
 *   rest: (stop: object, body: {id: string, issued: number},
 *          signal: AbortSignal) => Promise<{accepted: boolean, detail?: string,
 *          delivered?: number|null, road?: string, late_s?: number|null}>,
 *   door: (drone: string) => (import("./door.js").DoorConnection | null),
 *   serverNow: () => number, retryMs?: number, newId?: () => string,
 *   sleep?: (ms: number, signal: AbortSignal) => Promise<void>, fleet?: () => boolean,
 * }} roads
 */
export class StopSender extends EventTarget {
  constructor(roads) {
    super();
    this.roads = roads;
    this.retryMs = roads.retryMs ?? REST_RETRY_MS;
    this.newId = roads.newId ?? newStopId;
    this.sleep = roads.sleep ?? abortableSleep;
    /** @type {Map<string, object>} id -> stop, while pending */
    this.pending = new Map();
    /** @type {Map<string, object>} id -> superseded stop, until its door answers */
    this.dropped = new Map();
  }

  /** Send ``action`` to ``drone`` down every road now; returns the stop. ``source`` (button,
   *  keyboard) goes to the server's audit log. */
  send(drone, action, source = "button") {
    const stop = {
      id: this.newId(),
      drone,
      action,
      source,
      issued: this.roads.serverNow(),
      fleet: Boolean(this.roads.fleet?.()),
      state: "pending",
      ack: null,
      why: "",
      // server: "trying" | "done"; door: "trying" | "none" (this drone has no door) | "done"
      road: { server: "trying", door: this.roads.door(drone) ? "trying" : "none" },
      abort: new AbortController(),
      tryingRoads() {
        return Object.values(this.road).filter((r) => r === "trying").length;
      },
      text(offsetS) {
        return stopText(this, offsetS);
      },
    };
    this.pending.set(stop.id, stop);
    this.toDoor(stop);
    this.overRest(stop);
    this.changed(stop);
    return stop;
  }

  /** Send every pending stop of ``drone`` down its door (it has just opened again), and the
   *  supersedes it has not answered yet (the server road may bring those stops later). */
  doorOpened(drone) {
    const ids = [...this.dropped.values()].filter((s) => s.drone === drone).map((s) => s.id);
    if (ids.length) this.roads.door(drone)?.send({ op: "supersede", ids });
    for (const stop of this.pending.values()) {
      if (stop.drone === drone) {
        if (stop.road.door === "none") stop.road.door = "trying";
        this.toDoor(stop);
        this.changed(stop);
      }
    }
  }

  toDoor(stop) {
    const door = this.roads.door(stop.drone);
    if (!door) return false;
    return door.send({ op: "stop", action: stop.action, id: stop.id, issued: stop.issued });
  }

  async overRest(stop) {
    const body = { id: stop.id, issued: stop.issued };
    while (stop.state === "pending") {
      try {
        const res = await this.roads.rest(stop, body, stop.abort.signal);
        if (stop.state !== "pending") return;
        const confirmed = res && res.delivered !== null && res.delivered !== undefined;
        if (res && (confirmed || res.accepted === false)) {
          this.acked(stop, { ...res, via: "server" });
          return;
        }
      } catch (err) {
        if (stop.state !== "pending") return;
        const status = err && typeof err.status === "number" ? err.status : 0;
        // 401/403/404/422: this road will not carry it, however often it is asked
        if (status >= 400 && status < 500 && status !== 408 && status !== 409 && status !== 429) {
          stop.road.server = "done";
          stop.why = err.message || `HTTP ${status}`;
          this.roadGone(stop);
          return;
        }
      }
      try {
        await this.sleep(this.retryMs, stop.abort.signal);
      } catch {
        return; // aborted: acknowledged by the door, or superseded
      }
    }
  }

  /** A door's answer ({op: "ack"}) for one of our stops. */
  doorAck(msg) {
    const stop = this.pending.get(msg.id);
    if (stop) this.acked(stop, { ...msg, via: "door" });
    const gone = this.dropped.get(msg.id);
    if (gone && msg.accepted) this.ranAnyway(gone, { ...msg, via: "door" });
  }

  /** A door's answer ({op: "superseded", ids, too_late}) to a supersede: the stops in
   *  ``too_late`` had run before it arrived; the others will not run. */
  doorSuperseded(msg) {
    for (const id of Array.isArray(msg.ids) ? msg.ids : []) this.dropped.delete(id);
    for (const id of Array.isArray(msg.too_late) ? msg.too_late : []) {
      const stop = this.dropped.get(id);
      if (stop) this.ranAnyway(stop, { accepted: true, id, detail: "already run", via: "door" });
    }
  }

  ranAnyway(stop, ack) {
    this.dropped.delete(stop.id);
    stop.state = "ran";
    stop.ack = ack;
    this.changed(stop);
  }

  acked(stop, ack) {
    if (stop.state !== "pending") return;
    stop.ack = ack;
    stop.state = ack.accepted ? "delivered" : /supersed/i.test(ack.detail || "") ? "superseded" : "refused";
    stop.road.server = stop.road.server === "trying" ? "done" : stop.road.server;
    stop.road.door = stop.road.door === "trying" ? "done" : stop.road.door;
    this.pending.delete(stop.id);
    stop.abort.abort();
    this.changed(stop);
  }

  roadGone(stop) {
    if (stop.tryingRoads() > 0 || stop.state !== "pending") {
      this.changed(stop);
      return;
    }
    stop.state = "unsent";
    this.pending.delete(stop.id);
    stop.abort.abort();
    this.changed(stop);
  }

  /**
   * The operator issued a newer command: every pending stop is dropped (its door is told,
   * its REST request aborted). Returns the stops dropped.
   */
  supersede() {
    const dropped = [...this.pending.values()];
    if (!dropped.length) return dropped;
    const byDrone = new Map();
    for (const stop of dropped) {
      byDrone.set(stop.drone, [...(byDrone.get(stop.drone) || []), stop.id]);
    }
    for (const [drone, ids] of byDrone) {
      this.roads.door(drone)?.send({ op: "supersede", ids });
    }
    for (const stop of dropped) {
      stop.state = "superseded";
      this.pending.delete(stop.id);
      this.dropped.set(stop.id, stop);
      stop.abort.abort();
      this.changed(stop);
    }
    while (this.dropped.size > DROPPED_KEPT) this.dropped.delete(this.dropped.keys().next().value);
    return dropped;
  }

  changed(stop) {
    this.dispatchEvent(new CustomEvent("change", { detail: stop }));
  }
}

function abortableSleep(ms, signal) {
  return new Promise((resolve, reject) => {
    if (signal.aborted) {
      reject(new Error("aborted"));
      return;
    }
    const timer = setTimeout(resolve, ms);
    signal.addEventListener(
      "abort",
      () => {
        clearTimeout(timer);
        reject(new Error("aborted"));
      },
      { once: true },
    );
  });
}
